"""``python -m spade.bench [quick=true] [expert_ckpt=PATH] [sections=[...]]``: the project's performance figures.

One command measures, prints as Markdown tables, and writes as JSON (``out_json``):

- student batch-1 and batch-N latency per size, eager PyTorch and ONNX Runtime (``student``);
- conditional and unconditional expert seconds per sample, DDIM at several step counts vs the full DDPM loop
  (``experts``; random weights at the paper's presets where a CPU holds them);
- APE of DDIM-k against DDPM on a *trained* conditional expert, same initial noise (``quality``; ``expert_ckpt=``
  or a tiny expert trained here for ``quality.train_steps`` steps);
- training step time of BC, DBC and Cond-DBC with the same student and of the expert, their FLOP rate against a
  matmul's, each speed lever against the baseline, profiles and Lightning's overhead (``training``; with
  ``speed_page=docs/results/speed.md`` also written as that page);
- metric throughput and a per-instance reference pipeline on the same predictions (``metrics``; with
  ``metrics.sensitivity=true`` also how FID follows degradations), dataset generation and read throughput
  (``data``), annotation instances/s per worker at each window size and worker count (``annotation_scaling``);
- when named in ``sections``: the annotation tool's training presets (``annotation``), a large dataset read in a
  fresh process with its memory (``dataset``), real and procedural maps (``maps``);

then checks the targets of the deployment issue. ``quick=true`` runs everything at tiny sizes (CI);
``conf/bench.yaml`` lists every setting; the sections live in :mod:`spade.perf.bench`.
"""

from __future__ import annotations

import time

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.perf.bench import SECTIONS, bench  # noqa: F401  (also registers the ${quick_or:} resolver)
from spade.perf.bench_report import format_report, write_json


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="bench")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.bench_checks import validate_bench_config
    from spade.config.refusals import exit_on_user_error

    from spade.perf.training import LEVERS

    # a bad value: one `error:` line, exit 2, before any section
    options = exit_on_user_error(validate_bench_config)(cfg, SECTIONS, list(LEVERS))
    from spade.utils.provenance import command_line, commit

    t0, command, checkout = time.perf_counter(), command_line("spade.bench"), commit()  # the code that runs
    results = bench(cfg)
    path = write_json(results, options.out_json)
    print(format_report(results))
    print(f"\nJSON: {path}")
    if options.speed_page:
        from spade.perf.speed_page import write_speed_page

        page = write_speed_page(results, options.speed_page, command, checkout, time.perf_counter() - t0)
        print(f"Page: {page}")


if __name__ == "__main__":
    run_entry_point(main)
