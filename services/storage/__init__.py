"""Object storage for the service: which `Store` a process uses and each tenant's view of it
(`stores`), and the S3 adapter with its retries and the self-hosted servers' quirks (`s3_store`).

Why a package of its own: uploads, artifacts and results are the only things the service keeps
in a bucket; every key a request touches goes through `stores.tenant_store`, so isolation between
tenants is a property of this one package.
"""
