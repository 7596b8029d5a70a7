"""Demonstration annotation tool: sketches on occupancy maps -> executed paths -> dataset instances.

Modules: ``templates`` (L/U sketches), ``scenarios`` (goals, placement, per-scenario seeding), ``execution``
(Nav2-like planning on the inflated costmap of :mod:`spade.maps.costmap`, smoothing, checks), ``pipeline`` (process
pool, ordering, writing), ``sources`` (``maps=``), ``split`` (one map into a training and a test part that share
nothing: ``split=area:PART`` or ``split=scenario:PART``), ``sketch_file`` (operators' own sketches), ``preview``
(contact sheet), ``importers`` (rosbag2, SKIPP). ``run`` (one annotation run, :func:`spade.annotation.run.annotate`).
The CLI is :mod:`spade.annotate`.
The robot frame of the windows (:mod:`spade.maps.frame`) and their rasterisation into the four images
(:mod:`spade.data.rasterize`) live below this package, where the dataset writer, the metrics and the planner use
them too.
"""
