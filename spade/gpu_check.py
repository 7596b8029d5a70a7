"""``python -m spade.gpu_check [key=value ...]``: the paper's scale, briefly, on one NVIDIA GPU.

Expert and student training steps at 128 px with their peak memory (the 9.2M conditional expert, the
1-billion-parameter unconditional one, a medium student by BC and by Cond-DBC), the conditional expert's DDIM cost,
and a real ``t1_medium_conddbc_L`` run of a few hundred steps at ``scale=paper trainer=gpu`` (its expert trained
first); prints Markdown, writes JSON (``out_json``). ``conf/gpu_check.yaml`` lists every setting; the work lives in
:mod:`spade.perf.gpu`. Without a CUDA GPU it stops with one line (exit status 2) unless ``device=cpu``.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig, OmegaConf

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.perf.gpu import DeviceUnavailableError, format_gpu_report, gpu_check, write_json
from spade.utils.errors import exit_on_errors


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="gpu_check")
@task
def main(cfg: DictConfig) -> None:
    settings = {k: OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v
                for k, v in cfg.items() if k not in ("paths", "hydra", "out_json")}
    results = exit_on_errors((DeviceUnavailableError, ValueError))(gpu_check)(settings)
    path = write_json(results, cfg.out_json)
    print(format_gpu_report(results))
    print(f"\nJSON: {path}")


if __name__ == "__main__":
    run_entry_point(main)
