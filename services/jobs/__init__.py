"""The jobs domain: what submitting, cancelling and retrying jobs means, and the steps of a job's
life a worker takes (start a stage, record it done, finish), over the records (`common.jobs`,
`common.job_queue`, `scenes`).

Why a layer of its own: the API's routes used to hold the rules (validation, idempotency,
admission, the scene checks) and the worker its own copy of the state changes, so a rule lived
where its first caller happened to be. Now the routes translate HTTP to a call here and a refusal
(`refusals`) back to a status; the workers call `lifecycle`.
"""
