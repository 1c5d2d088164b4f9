"""Configuration: one spec per parameter (name, default, range, description, runtime flag), a node's table
of them, validation and parameter files (`parameters`); the geometry every node shares (beacon map, turret
offset, calibration file: `geometry_parameters`); how a command-line tool ends (`command_line`). A node's
own parameters live in its package's `parameters` module; a parameter two packages share lives here.
"""
