"""``python -m optitact``: the command line (same as ``optitact``)."""

if __name__ == "__main__":
    from optitact.cli import main

    raise SystemExit(main())
