"""MuJoCo as the reference simulator: our Go2 URDF in MuJoCo, physics cross-checks, sim2sim.

Modules: ``model`` (the URDF compiled into MuJoCo with the server's physics settings), ``sim``
(one robot stepped with the server's PD law), ``scenarios`` (the cross-check scenarios),
``crosscheck`` (ours against MuJoCo, figure by figure), ``observation`` (o_t exactly as the
server writes it), ``vec_env`` and ``sim2sim`` (an ONNX policy evaluated in MuJoCo), ``cli``
(``python -m unigait sim2sim`` / ``crosscheck``). Needs the ``mujoco`` extra
(``pip install 'unigait[mujoco]'``); nothing here is imported by ``import unigait``.
"""
