"""Text safe to serve (`text`): strings that always encode as UTF-8, and error messages without
internal locations (paths, tenant prefixes, bucket names).

Why a package of its own: the API's edge, the job records and the scene import all serve text
that someone else wrote; the rule for what a client may see is one rule.
"""
