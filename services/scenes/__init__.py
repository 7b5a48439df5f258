"""The scenes domain: what uploading, completing, deleting and sweeping a scene means, over two
ports (the scene rows, `ports.SceneRecords`; the bucket, the library's `Store`).

Why a package of its own: the API's scene routes used to lay out bucket keys, finish multipart
uploads, order a delete around row locks and call the tests' pause points, and the scene's rules
were spread over the API, `common` and the control process. Here each rule is written once:

- `model`, `refusals`: a scene's record and why a request about one is turned down;
- `store`: the rules over the rows (publish only an uploading scene, delete only one without an
  active job, a deleting row reads as absent), on a `ports.SceneRecords` (`postgres` in the
  service, an in-memory fake in the tests);
- `layout`: where a scene's objects live in the bucket;
- `intake`, `archives`: uploaded files -> a validated scene folder -> the bucket;
- `lifecycle`: upload, presigned start and completion, delete, and their ordering;
- `bucket_sweep`, `upload_temp`: what killed processes and half-done deletes leave behind;
- `legacy_import`: the rows of scenes that earlier releases recorded in the bucket.

The routes translate HTTP to a call here and the refusals back to a status (`api.edge`).
"""
