"""``python -m sonarmap``: the command line, as the ``sonarmap`` script (the team
launcher starts its node processes this way)."""

from sonarmap.cli import main

if __name__ == "__main__":
    main()
