"""``python -m hdrcl`` runs the command line."""
from hdrcl.cli import main

if __name__ == "__main__":
    main(prog_name="hdrcl")
