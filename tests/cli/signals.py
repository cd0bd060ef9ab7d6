"""For tests that send a real SIGINT to a child `terra` process."""

import signal


def ctrl_c_default() -> None:
    """`preexec_fn` of such a child: SIGINT back to its default, so that Python turns it into
    KeyboardInterrupt. A child inherits an ignored SIGINT from a suite started by `nohup` or as a
    background job, and then rightly ignores Ctrl-C, which is not what these tests check."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
