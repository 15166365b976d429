"""``python -m proto_brax.checkpoints``: see ``proto_brax.cli.checkpoints``."""

from proto_brax.startup import quiet_start

quiet_start()

from proto_brax.cli.checkpoints import main  # noqa: E402

main()
