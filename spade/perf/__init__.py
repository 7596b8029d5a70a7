"""Performance measurements behind ``python -m spade.bench``, one module per subject.

- :mod:`spade.perf.student` - student latency per size and batch, eager PyTorch and ONNX Runtime;
- :mod:`spade.perf.experts` - seconds per sample of the diffusion experts (DDIM / DDPM) and the APE of DDIM-k
  against the full DDPM loop;
- :mod:`spade.perf.training` - training steps of BC, DBC, Cond-DBC and the expert: time, FLOP rate against a
  matmul, each speed lever, profiles (FLOPs, the matmul reference and the profiler in :mod:`spade.perf.step_cost`,
  Lightning's per-step overhead in :mod:`spade.perf.lightning_overhead`);
- :mod:`spade.perf.speed_page` - the training section's results page (``docs/results/speed.md``); its bf16 science
  check is ``spade.report table=precision`` (:mod:`spade.experiments.precision_page`);
- :mod:`spade.perf.metrics` - APE + Hd19 and FID throughput, a per-instance reference pipeline, FID sensitivity;
- :mod:`spade.perf.throughput` - dataset-read and generation (annotation) throughput;
- :mod:`spade.perf.dataset` - a large dataset read in a fresh process, with its resident memory;
- :mod:`spade.perf.maps` - loading, resampling and generating maps;
- :mod:`spade.perf.bench_report` - the printed table and the JSON file.
- :mod:`spade.perf.bench` - the sections run together (``bench(cfg)``), what ``python -m spade.bench`` calls.

Every function returns plain dicts of numbers (JSON-ready) and prints nothing. Timing itself
(:func:`spade.utils.timing.measure`) and the machine description live in :mod:`spade.utils`, where training and
export use them too; synthetic paths and predictions come from :mod:`spade.metrics.synthetic`.
"""
