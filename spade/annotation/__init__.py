"""Demonstration annotation tool: sketches on occupancy maps -> executed paths -> dataset instances.

Modules: ``templates`` (L/U sketches), ``scenarios`` (goals, placement, per-scenario seeding), ``execution``
(Nav2-like planning on the inflated costmap, smoothing, checks), ``rasterize`` (windows and the four images),
``pipeline`` (process pool, ordering, writing), ``sources`` (``maps=``), ``sketch_file`` (operators' own
sketches), ``preview`` (contact sheet), ``importers`` (rosbag2, SKIPP). ``run`` (one annotation run, :func:`spade.annotation.run.annotate`). The CLI is :mod:`spade.annotate`.
"""
