"""Every command's config checks, before any work: typed options of each configurable and a preflight per command.

Importing this package loads nothing else; each command imports only its own module, lazily, so that
``import spade.train`` does not load the sketch, plan or export checks.

- :mod:`~spade.config.options`: :func:`~spade.config.options.read_options`, which builds a config node's typed
  options (one frozen dataclass per node, checking its own types and ranges in ``__post_init__``), and the options
  of the configurables ``spade.train`` builds (the data module, the student, the expert, the trainer's budget; the
  margin's are :class:`spade.training.margin.MarginConfig`); all but the budget live next to their configurable,
  which builds them too (:mod:`spade.data.datamodule_options`, :mod:`spade.training.module_options`);
- :mod:`~spade.config.preflight`: ``spade.train``'s options built once (:func:`~spade.config.preflight.
  train_options`) and, as functions of them, the checks that cross components (a checkpoint's role and geometry
  against the data, the store a run logs to, the run a resume continues);
- ``<command>_checks``: the other commands' (:mod:`~spade.config.evaluate_checks`,
  :mod:`~spade.config.annotate_checks`, :mod:`~spade.config.export_checks`, :mod:`~spade.config.plan_checks`,
  :mod:`~spade.config.bench_checks`, :mod:`~spade.config.report_checks`, :mod:`~spade.config.sketch_checks`,
  :mod:`~spade.config.critic_checks`);
- what they share: the checks of a value already read, :mod:`spade.utils.option_checks` (every floor may use
  them), :mod:`~spade.config.dataset_checks` (the ``data`` sources and the ``scale``),
  :mod:`~spade.config.window_checks`, :mod:`~spade.config.checkpoint_checks`, :mod:`~spade.config.file_checks` (inputs, outputs, maps, ``paths``),
  :mod:`~spade.config.store_checks` (MLflow stores), and :mod:`~spade.config.refusals` (how an entry point reports a user error: one line, exit status 2).

Every check raises :class:`~spade.utils.errors.ConfigError` (a :class:`~spade.utils.errors.UserError`) with one
line naming the key, its value and the fix.
"""
