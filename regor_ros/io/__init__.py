"""Files: point clouds in their formats, a robot's map with its trajectory, and the prepared-map cache.

The node, the command line, the benchmark and the batch all read clouds and maps; this layer sits
between them and the core (tools > ros > io > core), and imports only the core.
"""
