"""``python -m proto_brax.datasets``: make, export, inspect and list datasets
(the command line: ``proto_brax.cli.datasets``; the library: ``proto_brax.data.cache``)."""

if __name__ == "__main__":
    from proto_brax.startup import quiet_start

    quiet_start()
    from proto_brax.cli.datasets import main

    main()
