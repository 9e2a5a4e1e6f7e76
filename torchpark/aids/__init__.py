"""Agent-side aids: layers between a policy and the paper's simulator, each a configuration
(:mod:`torchpark.aids.config`) and pure tensor functions, all off by default. They call the
simulator (:mod:`torchpark.sim`); the simulator never calls them."""
