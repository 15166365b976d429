"""What the runs mean and what they cost: statistics (IQM, bootstrap CIs: ``stats``), a sweep's plots
(``report``; ``python -m proto_brax.report``), the published locomotion benchmark's plan and runner logic
(``locomotion_plan``) and its RESULTS.md (``results_md``), the cost benchmarks' interleaved timing (``timing``,
``throughput``) and the MJX-against-native-MuJoCo cross-checks (``crosscheck``)."""
