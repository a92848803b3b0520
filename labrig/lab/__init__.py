"""The lab station in the browser (``labrig lab``): watch the runs come in, close the
missing-physics loop with a click, ask the rig — a Panel page over the public verbs."""
