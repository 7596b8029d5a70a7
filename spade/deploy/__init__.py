"""Deployment of a trained student: export (``spade.deploy.export``: ONNX / TorchScript files that carry the
student's metadata, checked against PyTorch) and planning with an exported or checkpointed student
(``spade.deploy.planner``).

Kept import-light on purpose: import the submodule you need, e.g. ``from spade.deploy.export import
export_student``; nothing here pulls in onnx, onnxruntime or Lightning.
"""
