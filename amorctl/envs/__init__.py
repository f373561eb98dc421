"""Motion-tracking environments: the frame features, the batched MuJoCo simulation, the vector env."""
