"""``python -m amcp_drake``: the ``amcp`` command line."""

from amcp_drake.cli import main

if __name__ == "__main__":
    main()
