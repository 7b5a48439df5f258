"""The jobs domain: what submitting, cancelling and retrying jobs means, and the steps of a job's
life a worker takes (start a stage, record it done, finish), over the records and the live state
through its ports (`ports`).

Modules: `model` (the record, its states and the write rules), `store` (`JobStore`: rows and live
state through the ports, a job's end writing its outbox and usage rows), `ports` (the records and
live ports with their PostgreSQL / Redis implementations), `queue` (fair share and admission),
`batches` (the batch model and its status rule), `usage` (what a job cost), `service` (submit,
cancel, retry), `lifecycle` (a worker's steps), `validation`, `refusals`, `answers`,
`durable_writes`.

Why a layer of its own: the API's routes used to hold the rules (validation, idempotency,
admission, the scene checks) and the worker its own copy of the state changes, so a rule lived
where its first caller happened to be. Now the routes translate HTTP to a call here and a refusal
(`refusals`) back to a status; the workers call `lifecycle`.
"""
