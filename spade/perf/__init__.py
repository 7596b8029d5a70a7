"""Performance measurements behind ``python -m spade.bench``, one module per subject.

- :mod:`spade.perf.timing` - median / min wall time of a callable, machine description;
- :mod:`spade.perf.student` - student latency per size and batch, eager PyTorch and ONNX Runtime;
- :mod:`spade.perf.experts` - seconds per sample of the diffusion experts (DDIM / DDPM) and the APE of DDIM-k
  against the full DDPM loop;
- :mod:`spade.perf.training` - training step time of BC, DBC and Cond-DBC with the same student;
- :mod:`spade.perf.throughput` - metric, dataset-read and generation (annotation) throughput;
- :mod:`spade.perf.report` - the printed table and the JSON file.
- :mod:`spade.perf.bench` - the sections run together (``bench(cfg)``), what ``python -m spade.bench`` calls.

Every function returns plain dicts of numbers (JSON-ready) and prints nothing.
"""
