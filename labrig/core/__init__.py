"""The shared ground every layer stands on: errors and their exit codes, atomic file
writing, file schemas, text tables, figure style, timing and the version.
"""
