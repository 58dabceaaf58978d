"""``python -m spidermatch.cli_eval``: the same as the ``spidermatch-eval`` command."""

from spidermatch.cli import eval_main

if __name__ == "__main__":
    eval_main()
