"""Agent-side aids: the layers composed into the step between a policy and the paper's
simulator (emergency brake, docking law, held actions, near-goal starts, the aided step),
each a configuration (:mod:`torchpark.aids.config`) and pure tensor functions, all off by
default. They call the simulator (:mod:`torchpark.sim`); the simulator never calls them."""
