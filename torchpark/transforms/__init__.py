"""Policy-side TorchRL transforms: what a policy reads (extra features of the observation)
and how its output becomes the env's action (action maps). They sit between the env and the
networks in a ``TransformedEnv``; the env's step never calls them. ``sync_free``: the
``TransformedEnv`` and transforms whose ``step_and_maybe_reset`` reads nothing back per
step."""
