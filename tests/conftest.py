import os
import sys

sys.path.insert(0, os.path.dirname(__file__))  # tests/reference.py

# The commands the tests start (python -m proto_brax.sweep ...) inherit this: no JAX persistent compilation cache, so
# they neither write into the user's ~/.cache nor pay for serializing programs that a fresh CI machine never reuses
# (test_startup checks the cache itself).
os.environ["PROTO_BRAX_JAX_CACHE"] = ""
