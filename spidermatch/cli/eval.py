"""``python -m spidermatch.cli.eval``: the same as the ``spidermatch-eval`` command."""

from spidermatch.cli.main import eval_main

if __name__ == "__main__":
    eval_main()
