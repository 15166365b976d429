"""Imported first by every benchmark script (before anything that loads MuJoCo or Brax): the command lines' quiet
start, ``proto_brax.startup.quiet_start`` (the known start-up noise of our dependencies filtered, nothing else)."""

from proto_brax.startup import quiet_start

quiet_start()
