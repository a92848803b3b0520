"""Files in and out: run files and their sidecars, foreign CSV / MATLAB imports, rig and
plan files, the experiments a plan holds, steady-state tables and mystery-rig files.
"""
