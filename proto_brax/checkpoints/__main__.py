"""``python -m proto_brax.checkpoints``: see ``proto_brax.checkpoints.cli``."""

from proto_brax.startup import quiet_start

quiet_start()

from proto_brax.checkpoints.cli import main  # noqa: E402

main()
