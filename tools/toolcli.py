"""Command-line pieces shared by the Python tools (tools/train_live.py, research/eval_detector.py):
a bad command line is one line naming the program and exit 2, a failure one line and exit 1,
and whole-number arguments checked by argparse. Run as scripts, the tools find this file beside
them."""

import argparse
import sys


class Parser(argparse.ArgumentParser):
    """argparse, with its errors as one line "PROGRAM: error: ... (see --help)" and exit 2."""

    def __init__(self, program, **kwargs):
        # "--iteration 5" is not "--iterations 5": no abbreviations
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(**kwargs)
        self.program = program

    def error(self, message):
        sys.stderr.write("%s: error: %s (see --help)\n" % (self.program, message))
        sys.exit(2)


def fail(program, message):
    """One line "PROGRAM: error: MESSAGE" on stderr, then exit 1."""
    sys.stderr.write("%s: error: %s\n" % (program, message))
    sys.exit(1)


def whole_number(minimum):
    """An argparse type: a whole number >= minimum."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError("wants a whole number, got %r" % text) from None
        if value < minimum:
            raise argparse.ArgumentTypeError("wants a whole number >= %d, got %r" %
                                             (minimum, text))
        return value
    return parse
