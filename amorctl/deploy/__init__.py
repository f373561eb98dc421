"""``amorctl deploy``: the policy as an ONNX bundle whose weights ``w`` are a run-time input, and a
torch-free sim-to-sim runtime for it (docs/deploy.md).

- :mod:`amorctl.deploy.export` (needs torch): run directory -> bundle (``policy.onnx`` with the
  normalizer and the actor's mean baked in, ``deploy.json``, ``motions.npz``), parity-checked.
- :mod:`amorctl.deploy.bundle`: the bundle format, read and validated without torch.
- :mod:`amorctl.deploy.runtime` and its ``runtime_*`` modules: the sim2sim runtime (numpy,
  mujoco, onnxruntime only); :mod:`amorctl.deploy.check`: uniform vs tuned weights under
  randomized dynamics.
"""
