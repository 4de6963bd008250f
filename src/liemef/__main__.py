"""``python -m liemef``: the command line, as the ``liemef`` console script."""

from .cli import main

if __name__ == "__main__":
    main()
