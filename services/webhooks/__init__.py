"""Callbacks to the users' URLs: the transactional outbox and its sender (`callbacks`), one
bounded delivery attempt (`callback_delivery`), the check of a destination before submit and
before every POST (`callback_destinations`) and the Standard Webhooks signature headers of each
attempt (`signing`).

Why a package of its own: delivering to hosts the users name is the service's one outgoing
traffic, with its own security rules (no private addresses, pinned resolution) and its own
failure mode (at least once, never on a job's path).
"""
