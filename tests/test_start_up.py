"""A Ctrl-C or SIGTERM while a program still loads (issue 53, item 4: the launcher's first second ignored it, 9 of 9
tries; other programs gave a traceback): the program ends at once with its documented code and one line."""
import signal
import subprocess
import sys

import pytest

RUN = ("import sys; sys.path.insert(0, {path!r})\n"
       "from aoa_localizer.common.start_up import program\n"
       "sys.exit(program('demo', 'slow_module', interrupted=7)())\n")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("ignored_at_start", [False, True])
def test_a_signal_while_the_program_loads_ends_it_with_its_code(tmp_path, sig, ignored_at_start):
    """The module sends itself the signal mid-import (as a Ctrl-C during numpy's import would come), also in a
    process started with SIGINT ignored (a shell's background job); after the import its own handlers rule."""
    (tmp_path / "slow_module.py").write_text(
        f"import os, time\nos.kill(os.getpid(), {int(sig)})\ntime.sleep(20)\ndef main():\n    return 0\n")
    preexec = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignored_at_start else None
    res = subprocess.run([sys.executable, "-c", RUN.format(path=str(tmp_path))], capture_output=True, text=True,
                         timeout=15, preexec_fn=preexec)
    assert res.returncode == 7 and res.stderr.strip() == f"demo: stopped by {sig.name} while starting", res.stderr


def test_after_loading_the_handlers_are_what_they_were(tmp_path):
    """Once loaded, the program's main runs under the process's own handlers (Python's KeyboardInterrupt here). The
    child starts with SIGINT at its default, as at a terminal: a suite run as a background job starts its children
    with SIGINT ignored, which Python keeps, and then "what they were" is ignored."""
    (tmp_path / "slow_module.py").write_text(
        "import signal\ndef main():\n    return 0 if signal.getsignal(signal.SIGINT) is signal.default_int_handler "
        "else 3\n")
    res = subprocess.run([sys.executable, "-c", RUN.format(path=str(tmp_path))], capture_output=True, text=True,
                         timeout=15, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert res.returncode == 0, res.stderr
