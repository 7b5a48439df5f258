"""Who is calling: the API key ring (`api_keys`: hashed keys from the settings or a secret file,
each mapped to its tenant) and the request dependency that resolves a key to a tenant (`auth`).

Why apart from the API: the operator's tools hash keys too (`api_keys.hash_api_key`), and the
rules for keys are one job that neither the routes nor the settings should spell.
"""
