"""What the runs mean: statistics (IQM, bootstrap CIs), the published locomotion benchmark's plan and its
RESULTS.md. The per-sweep plots stay in ``proto_brax.report`` (``python -m proto_brax.report``)."""
