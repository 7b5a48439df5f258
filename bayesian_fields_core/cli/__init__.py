"""The `bfields` command line: the verbs (`main`), what they print (`output`, `report`,
`progress`), the cache, parameter-table and viewer commands. The top of the library: nothing
below imports it. The service's verbs plug in through entry points (see `main.CLI_PLUGIN_GROUP`).
"""
