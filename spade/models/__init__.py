"""SPADE's networks: the SKIPP-style student U-Nets, the two diffusion experts and their noise schedule.

Nothing is imported here, so that a torch-free module of this package (:mod:`~spade.models.paper_sizes`,
:mod:`~spade.models.onnx_session`, :mod:`~spade.models.onnx_check`) imports without torch. Import each name from its
module: :mod:`~spade.models.builders` (``build_model``, ``model_from_config``, ``presets``, ``ROLES``,
``count_parameters``), :mod:`~spade.models.student`, :mod:`~spade.models.cond_expert`,
:mod:`~spade.models.uncond_expert`, :mod:`~spade.models.diffusion` (``NoiseSchedule``, samplers, model ranges),
:mod:`~spade.models.modelfile` (checkpoints and exports).
"""
