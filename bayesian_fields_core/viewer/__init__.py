"""`bfields view`: an interactive browser viewer of a result (viser). `data` holds the GUI-free
parts (loading, colourings, picking); `server` the viser scene and panel; `command` the CLI."""
