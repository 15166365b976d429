"""``python -m proto_brax.report``: figures and a JSON digest of sweep directories
(the command line: ``proto_brax.cli.report``; the library: ``proto_brax.analysis.report``)."""

if __name__ == "__main__":
    from proto_brax.startup import quiet_start

    quiet_start()
    from proto_brax.cli.report import main

    main()
