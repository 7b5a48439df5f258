"""The job runtime: the stage table, the three parts of a job (what it is, `spec.JobSpec`; what it
runs on, `job_scene.JobScene`; what runs it, `runner.Runner`) and the factories that build them
(`factories`), the pipeline that runs the stages in order and resumes finished ones, the artifact
store, artifact names, completion markers, content keys of the caches and their index, and where a
job's scene folder comes from.

It sits below `stages/`: a stage imports the job's parts and the store; the runtime finds the
stage functions through the table (`stage_table.StageSpec.function`), never by importing a stage.
"""
