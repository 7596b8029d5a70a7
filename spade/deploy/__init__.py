"""Deployment of a trained student: export (``spade.deploy.export``: ONNX / TorchScript files that carry the
student's metadata, checked against PyTorch), planning in the robot frame with an exported or checkpointed student
(``spade.deploy.student_planner``; the query's window in ``spade.deploy.robot_window``, the robot's footprint
check in ``spade.deploy.footprint``), its pictures (``spade.deploy.plan_picture``) and what ``python -m spade.plan``
runs (``spade.deploy.plan_command``). Model files themselves are read and written by :mod:`spade.models.modelfile`.

Kept import-light on purpose: import the submodule you need, e.g. ``from spade.deploy.export import
export_student``; nothing here pulls in onnx, onnxruntime or Lightning.
"""
