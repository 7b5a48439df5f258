"""Checks beside scene I/O: does a splat line up with its cameras (`alignment`, rendered in
`alignment_render`), and is an uploaded folder complete and readable (`upload`). The readers in
`scene/` load; these decide whether what was loaded can give a meaningful answer."""
