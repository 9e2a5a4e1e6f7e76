"""The paper's simulator as pure tensor functions: geometry (oriented boxes, SAT, rays),
the kinematic bicycle, LIDAR, the static lot (layout) and its per-episode draws (episodes),
the shared constants (world), the observation, Table 1's reward, and the step and reset.
Nothing here imports from ``torchpark.aids``, ``torchpark.media`` or the trainers."""
