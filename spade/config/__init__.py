"""Every command's config checks, before any work: typed options of each configurable and a preflight per command.

Importing this package loads nothing else; each command imports only its own module, lazily, so that
``import spade.train`` does not load the sketch, plan or export checks.

- :mod:`~spade.config.options`: the typed options of the configurables ``spade.train`` builds (the data module,
  the student, the expert, the trainer's budget; the margin's are :class:`spade.training.margin.MarginConfig`),
  each checking its own types and ranges in ``__post_init__``; all but the budget live next to their
  configurable, which builds them too (:mod:`spade.data.datamodule_options`, :mod:`spade.training.module_options`);
- :mod:`~spade.config.preflight`: ``spade.train``'s checks, those that cross components (a checkpoint's role and
  geometry against the data, the store a run logs to, the run a resume continues) and the options above;
- ``<command>_checks``: the other commands' (:mod:`~spade.config.evaluate_checks`,
  :mod:`~spade.config.annotate_checks`, :mod:`~spade.config.export_checks`, :mod:`~spade.config.plan_checks`,
  :mod:`~spade.config.bench_checks`, :mod:`~spade.config.report_checks`, :mod:`~spade.config.sketch_checks`,
  :mod:`~spade.config.critic_checks`);
- what they share: :mod:`~spade.config.values` (typed getters of string keys, for the commands' own keys; the
  checks of a value already read are :mod:`spade.utils.option_checks`, which every floor may use),
  :mod:`~spade.config.dataset_checks`, :mod:`~spade.config.window_checks`, :mod:`~spade.config.checkpoint_checks`,
  :mod:`~spade.config.file_checks` (inputs, outputs, maps), :mod:`~spade.config.store_checks` (MLflow stores), and
  :mod:`~spade.config.refusals` (how an entry point reports a user error: one line, exit status 2).

Every check raises :class:`~spade.utils.errors.ConfigError` (a :class:`~spade.utils.errors.UserError`) with one
line naming the key, its value and the fix.
"""
