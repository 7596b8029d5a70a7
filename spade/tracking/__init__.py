"""A run's MLflow record, in one place, and how a person opens it in the MLflow UI.

The one entry from training is the callback :class:`~spade.tracking.callback.RunRecord` (``run_record`` in
``conf/callbacks/default.yaml``) with SPADE's MLflow logger (:mod:`~spade.tracking.logger`,
``conf/logger/mlflow.yaml``). One module per job:

- :mod:`~spade.tracking.client`: the one way an MLflow store is opened (:func:`mlflow_client`, a fresh SQLite
  store under a lock) and the registry alias ``champion`` (:data:`CHAMPION_ALIAS`);
- :mod:`~spade.tracking.callback`: the run's record from its first stage to its last (opened, described, closed);
- :mod:`~spade.tracking.logger`: SPADE's MLflow logger (references held back for the child runs, test figures at
  one step, the margin on the validation's axis, the run opened safely and closed once);
- :mod:`~spade.tracking.runs`: the record's steps (bind, config and process, status, description, stale runs);
- :mod:`~spade.tracking.links`: the MLflow UI's address, the URLs of runs, runs tables and artifacts, and the
  ``mlflow ui`` command (:func:`ui_lines`, printed at the end of training and by ``spade.report``);
- :mod:`~spade.tracking.experiment_tags`: an experiment's metadata: tagged as model training, its description
  (the paper table it reproduces and how to regenerate it) and SPADE's runs view;
- :mod:`~spade.tracking.dataset_inputs`: a run's datasets as MLflow dataset inputs;
- :mod:`~spade.tracking.descriptions`: a run's description and the descriptions of the models it registers;
- :mod:`~spade.tracking.logged_model`: a student run's best checkpoint as the run's own MLflow Model ``model``;
- :mod:`~spade.tracking.params`: a run's parameters, the settings that describe the method;
- :mod:`~spade.tracking.predictors`: the classical baselines and the untrained model as child runs;
- :mod:`~spade.tracking.progress_picture`: the run's training, epoch by epoch, as a picture;
- :mod:`~spade.tracking.registry`: models in the MLflow Model Registry, pinned by alias;
- :mod:`~spade.tracking.run_report`: the run's report, ``report/run_report.md`` and ``report/test_figures.csv``;
- :mod:`~spade.tracking.summary`: the closing lines of ``spade.train`` and ``spade.evaluate``;
- :mod:`~spade.tracking.report`: ``spade.report``'s table published in MLflow;
- :mod:`~spade.tracking.tables`: the paper's tables, each an MLflow experiment of runs named after its rows (what
  the experiments' descriptions, the runs view and ``spade.report`` read).

Nothing is imported here, so that a torch- and Lightning-free module of this package (predictors, links,
run_report, client) imports without the ones that need Lightning (runs, logger): import each name from its module.
"""
