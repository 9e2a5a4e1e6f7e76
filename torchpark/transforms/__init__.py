"""Policy-side TorchRL transforms: what a policy reads (extra features of the observation)
and how its output becomes the env's action (action maps). They sit between the env and the
networks in a ``TransformedEnv``; the env's step never calls them."""
