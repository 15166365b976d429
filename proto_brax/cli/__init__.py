"""The command lines: tyro arguments and ``main()`` only; the work is in ``proto_brax.experiment`` (sweeps,
pretraining), ``proto_brax.data`` (datasets), ``proto_brax.checkpoints`` and ``proto_brax.analysis`` (reports).
``python -m proto_brax.sweep`` (and ``.pretrain``, ``.datasets``, ``.report``, ``.checkpoints``) run these."""
