"""What the runs mean and what they cost: statistics (IQM, bootstrap CIs), the published locomotion benchmark's plan
and its RESULTS.md, and the cost benchmarks' interleaved timing (``timing``). The per-sweep plots stay in
``proto_brax.report`` (``python -m proto_brax.report``)."""
