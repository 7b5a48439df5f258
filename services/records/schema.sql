-- The records' current schema (PostgreSQL), generated: do not edit by hand.
-- Tables and indexes: `tables.metadata`; functions and triggers: the migrations named below.
-- Rewrite with: PYTHONPATH=$PWD python -m bayesian_fields_service.records.schema --write

CREATE TABLE batches (
    id VARCHAR(40) NOT NULL,
    tenant VARCHAR(64) NOT NULL,
    priority VARCHAR(16) NOT NULL,
    callback_url TEXT,
    job_count INTEGER NOT NULL,
    callback_enqueued BOOLEAN DEFAULT false NOT NULL,
    idempotency_key VARCHAR(255),
    queued INTEGER DEFAULT '0' NOT NULL,
    running INTEGER DEFAULT '0' NOT NULL,
    succeeded INTEGER DEFAULT '0' NOT NULL,
    failed INTEGER DEFAULT '0' NOT NULL,
    cancelled INTEGER DEFAULT '0' NOT NULL,
    active_progress DOUBLE PRECISION DEFAULT '0' NOT NULL,
    created_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    finished_at TIMESTAMP WITH TIME ZONE,
    CONSTRAINT pk_batches PRIMARY KEY (id),
    CONSTRAINT ck_batches_priority CHECK (priority IN ('interactive', 'bulk'))
);

CREATE INDEX ix_batches_tenant_created_at_id ON batches (tenant, created_at, id);

CREATE TABLE callback_outbox (
    id BIGSERIAL NOT NULL,
    tenant VARCHAR(64) NOT NULL,
    url TEXT NOT NULL,
    event JSONB NOT NULL,
    attempts INTEGER DEFAULT '0' NOT NULL,
    next_attempt_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    delivered_at TIMESTAMP WITH TIME ZONE,
    last_error TEXT,
    created_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    event_id VARCHAR(255) NOT NULL,
    dropped_at TIMESTAMP WITH TIME ZONE,
    CONSTRAINT pk_callback_outbox PRIMARY KEY (id),
    CONSTRAINT uq_callback_outbox_event_id UNIQUE (event_id)
);

CREATE INDEX ix_callback_outbox_due ON callback_outbox (next_attempt_at, id) WHERE delivered_at IS NULL AND dropped_at IS NULL;

CREATE TABLE control_leases (
    name VARCHAR(64) NOT NULL,
    holder VARCHAR(255) NOT NULL,
    token BIGINT NOT NULL,
    expires_at TIMESTAMP WITH TIME ZONE NOT NULL,
    CONSTRAINT pk_control_leases PRIMARY KEY (name)
);

CREATE TABLE idempotency_keys (
    tenant VARCHAR(64) NOT NULL,
    endpoint VARCHAR(64) NOT NULL,
    key VARCHAR(255) NOT NULL,
    body_sha256 VARCHAR(64) NOT NULL,
    target_id VARCHAR(40) NOT NULL,
    created_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    CONSTRAINT pk_idempotency_keys PRIMARY KEY (tenant, endpoint, key)
);

CREATE TABLE scenes (
    id VARCHAR(40) NOT NULL,
    tenant VARCHAR(64) NOT NULL,
    name VARCHAR(255),
    state VARCHAR(16) NOT NULL,
    files INTEGER DEFAULT '0' NOT NULL,
    bytes BIGINT DEFAULT '0' NOT NULL,
    summary JSONB DEFAULT '{}' NOT NULL,
    pending_uploads JSONB DEFAULT '[]' NOT NULL,
    created_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    updated_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    CONSTRAINT pk_scenes PRIMARY KEY (id),
    CONSTRAINT ck_scenes_state CHECK (state IN ('uploading', 'ready', 'deleting'))
);

CREATE INDEX ix_scenes_tenant_created_at_id ON scenes (tenant, created_at, id);

CREATE TABLE usage_ledger (
    id BIGSERIAL NOT NULL,
    entry_id VARCHAR(255) NOT NULL,
    tenant VARCHAR(64) NOT NULL,
    job_id VARCHAR(40) NOT NULL,
    kind VARCHAR(8) NOT NULL,
    stage VARCHAR(32),
    state VARCHAR(16),
    cpu_s DOUBLE PRECISION DEFAULT '0' NOT NULL,
    gpu_s DOUBLE PRECISION DEFAULT '0' NOT NULL,
    bytes_stored BIGINT DEFAULT '0' NOT NULL,
    recorded_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    CONSTRAINT pk_usage_ledger PRIMARY KEY (id),
    CONSTRAINT ck_usage_ledger_kind CHECK (kind IN ('stage', 'end')),
    CONSTRAINT uq_usage_ledger_entry_id UNIQUE (entry_id)
);

CREATE INDEX ix_usage_ledger_tenant_recorded_at ON usage_ledger (tenant, recorded_at);

CREATE TABLE jobs (
    id VARCHAR(40) NOT NULL,
    tenant VARCHAR(64) NOT NULL,
    scene_id VARCHAR(40) NOT NULL,
    batch_id VARCHAR(40),
    state VARCHAR(16) DEFAULT 'queued' NOT NULL,
    priority VARCHAR(16) NOT NULL,
    tasks JSONB NOT NULL,
    parameters JSONB DEFAULT '{}' NOT NULL,
    model_profile VARCHAR(64) NOT NULL,
    stage VARCHAR(32),
    progress DOUBLE PRECISION DEFAULT '0' NOT NULL,
    stages_done JSONB DEFAULT '[]' NOT NULL,
    timings JSONB DEFAULT '{}' NOT NULL,
    stage_reports JSONB DEFAULT '{}' NOT NULL,
    usage JSONB DEFAULT '{}' NOT NULL,
    error TEXT,
    cancel_requested BOOLEAN DEFAULT false NOT NULL,
    stage_runs INTEGER DEFAULT '0' NOT NULL,
    callback_url TEXT,
    retry_of VARCHAR(40),
    idempotency_key VARCHAR(255),
    worker VARCHAR(255),
    heartbeat_at TIMESTAMP WITH TIME ZONE,
    recoveries INTEGER DEFAULT '0' NOT NULL,
    created_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    updated_at TIMESTAMP WITH TIME ZONE DEFAULT now() NOT NULL,
    dispatched_at TIMESTAMP WITH TIME ZONE,
    started_at TIMESTAMP WITH TIME ZONE,
    finished_at TIMESTAMP WITH TIME ZONE,
    traceparent VARCHAR(64),
    CONSTRAINT pk_jobs PRIMARY KEY (id),
    CONSTRAINT ck_jobs_state CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    CONSTRAINT ck_jobs_priority CHECK (priority IN ('interactive', 'bulk')),
    CONSTRAINT fk_jobs_batch_id_batches FOREIGN KEY(batch_id) REFERENCES batches (id) ON DELETE CASCADE
);

CREATE INDEX ix_jobs_active ON jobs (tenant, id) WHERE state IN ('queued', 'running');

CREATE INDEX ix_jobs_batch_id_id ON jobs (batch_id, id);

CREATE INDEX ix_jobs_dispatch_times ON jobs (tenant, dispatched_at) WHERE dispatched_at IS NOT NULL;

CREATE INDEX ix_jobs_dispatched ON jobs (tenant, id) WHERE dispatched_at IS NOT NULL AND state IN ('queued', 'running');

CREATE INDEX ix_jobs_retry_of ON jobs (retry_of);

CREATE INDEX ix_jobs_scene_id ON jobs (scene_id);

CREATE INDEX ix_jobs_tenant_created_at_id ON jobs (tenant, created_at, id);

CREATE INDEX ix_jobs_tenant_state_created_at_id ON jobs (tenant, state, created_at, id);

CREATE INDEX ix_jobs_waiting ON jobs (tenant, priority, created_at, id) WHERE state = 'queued' AND dispatched_at IS NULL;

CREATE TABLE answers (
    job_id VARCHAR(40) NOT NULL,
    task_index INTEGER NOT NULL,
    rank INTEGER NOT NULL,
    tenant VARCHAR(64) NOT NULL,
    scene_id VARCHAR(40) NOT NULL,
    finished_at TIMESTAMP WITH TIME ZONE NOT NULL,
    task TEXT NOT NULL,
    found BOOLEAN NOT NULL,
    object_id INTEGER,
    content_key VARCHAR(64),
    probability DOUBLE PRECISION,
    best_view_score DOUBLE PRECISION,
    score DOUBLE PRECISION,
    ranked_by VARCHAR(16),
    num_gaussians INTEGER,
    frame VARCHAR(8),
    centre_x DOUBLE PRECISION,
    centre_y DOUBLE PRECISION,
    centre_z DOUBLE PRECISION,
    extent_x DOUBLE PRECISION,
    extent_y DOUBLE PRECISION,
    extent_z DOUBLE PRECISION,
    centroid_x DOUBLE PRECISION,
    centroid_y DOUBLE PRECISION,
    centroid_z DOUBLE PRECISION,
    rotation JSONB,
    preview VARCHAR(255),
    not_found_reason TEXT,
    CONSTRAINT pk_answers PRIMARY KEY (job_id, task_index, rank),
    CONSTRAINT ck_answers_rank CHECK (rank >= 0 AND task_index >= 0),
    CONSTRAINT fk_answers_job_id_jobs FOREIGN KEY(job_id) REFERENCES jobs (id) ON DELETE CASCADE
);

CREATE INDEX ix_answers_latest ON answers (tenant, task, scene_id, finished_at, job_id) INCLUDE (task_index, rank, found, probability) WHERE rank <= 1;

CREATE INDEX ix_answers_tenant_scene_id ON answers (tenant, scene_id);

CREATE INDEX ix_answers_tenant_task_scene_id_finished_at ON answers (tenant, task, scene_id, finished_at);

CREATE TABLE batch_jobs (
    batch_id VARCHAR(40) NOT NULL,
    position INTEGER NOT NULL,
    job_id VARCHAR(40) NOT NULL,
    CONSTRAINT pk_batch_jobs PRIMARY KEY (batch_id, position),
    CONSTRAINT fk_batch_jobs_batch_id_batches FOREIGN KEY(batch_id) REFERENCES batches (id) ON DELETE CASCADE,
    CONSTRAINT fk_batch_jobs_job_id_jobs FOREIGN KEY(job_id) REFERENCES jobs (id)
);

CREATE INDEX ix_batch_jobs_job_id ON batch_jobs (job_id);

-- functions and triggers of migration 0003_batch_statements.py
CREATE FUNCTION bf_apply_batch_deltas(changes jsonb) RETURNS void LANGUAGE sql AS $$
  WITH c AS (
    SELECT (e->>'batch_id') AS batch_id, (e->>'state') AS state,
           (e->>'progress')::double precision AS progress, (e->>'sign')::int AS sign
    FROM jsonb_array_elements(changes) AS e
  ), d AS (
    SELECT batch_id,
      coalesce(sum(sign) FILTER (WHERE state = 'queued'), 0) AS queued,
      coalesce(sum(sign) FILTER (WHERE state = 'running'), 0) AS running,
      coalesce(sum(sign) FILTER (WHERE state = 'succeeded'), 0) AS succeeded,
      coalesce(sum(sign) FILTER (WHERE state = 'failed'), 0) AS failed,
      coalesce(sum(sign) FILTER (WHERE state = 'cancelled'), 0) AS cancelled,
      coalesce(sum(sign * progress) FILTER (WHERE state IN ('queued', 'running')), 0) AS progress
    FROM c GROUP BY batch_id
  )
  UPDATE batches b SET
    queued = b.queued + d.queued, running = b.running + d.running,
    succeeded = b.succeeded + d.succeeded, failed = b.failed + d.failed,
    cancelled = b.cancelled + d.cancelled, active_progress = b.active_progress + d.progress
  FROM d WHERE b.id = d.batch_id
$$;

CREATE FUNCTION bf_batch_counts_on_jobs() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  PERFORM bf_apply_batch_deltas(coalesce((
    SELECT jsonb_agg(x) FROM (
      SELECT bj.batch_id, n.state, n.progress, 1 AS sign
        FROM new_rows n JOIN old_rows o ON o.id = n.id JOIN batch_jobs bj ON bj.job_id = n.id
        WHERE n.state IS DISTINCT FROM o.state OR n.progress IS DISTINCT FROM o.progress
      UNION ALL
      SELECT bj.batch_id, o.state, o.progress, -1
        FROM new_rows n JOIN old_rows o ON o.id = n.id JOIN batch_jobs bj ON bj.job_id = o.id
        WHERE n.state IS DISTINCT FROM o.state OR n.progress IS DISTINCT FROM o.progress
    ) x), '[]'::jsonb));
  RETURN NULL;
END $$;
CREATE TRIGGER bf_batch_counts_on_jobs AFTER UPDATE ON jobs
  REFERENCING OLD TABLE AS old_rows NEW TABLE AS new_rows
  FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_jobs();

CREATE FUNCTION bf_batch_counts_on_links() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE entering jsonb := '[]'; leaving jsonb := '[]';
BEGIN
  IF TG_OP IN ('INSERT', 'UPDATE') THEN
    SELECT coalesce(jsonb_agg(x), '[]') INTO entering FROM (
      SELECT l.batch_id, j.state, j.progress, 1 AS sign FROM new_links l JOIN jobs j ON j.id = l.job_id
    ) x;
  END IF;
  IF TG_OP IN ('DELETE', 'UPDATE') THEN
    SELECT coalesce(jsonb_agg(x), '[]') INTO leaving FROM (
      SELECT l.batch_id, j.state, j.progress, -1 AS sign FROM old_links l JOIN jobs j ON j.id = l.job_id
    ) x;
  END IF;
  PERFORM bf_apply_batch_deltas(entering || leaving);
  RETURN NULL;
END $$;
CREATE TRIGGER bf_batch_counts_on_link_insert AFTER INSERT ON batch_jobs
  REFERENCING NEW TABLE AS new_links FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_links();
CREATE TRIGGER bf_batch_counts_on_link_update AFTER UPDATE ON batch_jobs
  REFERENCING OLD TABLE AS old_links NEW TABLE AS new_links
  FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_links();
CREATE TRIGGER bf_batch_counts_on_link_delete AFTER DELETE ON batch_jobs
  REFERENCING OLD TABLE AS old_links FOR EACH STATEMENT EXECUTE FUNCTION bf_batch_counts_on_links();
