"""The run's log: other packages' warnings and stderr go to the log file, not the terminal."""

import logging
import subprocess
import sys
import textwrap


def test_warnings_and_stderr_go_to_the_log_not_the_terminal(tmp_path):
    log = tmp_path / "out" / "nerfify.log"
    script = textwrap.dedent(f"""
        import sys, warnings
        from nerfify_ns.runlog import quiet_console, run_log
        quiet_console()
        warnings.warn("held before the log exists", FutureWarning)
        with run_log({str(log)!r}):
            warnings.warn("a third-party deprecation", DeprecationWarning)
            print("noise on stderr", file=sys.stderr)
            import logging
            logging.getLogger("somepackage").warning("a library's warning")
        print("stdout still works")
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "stdout still works\n" and done.stderr == ""
    text = log.read_text()
    for needle in ("FutureWarning: held before the log exists", "DeprecationWarning: a third-party deprecation",
                   "noise on stderr", "somepackage: a library's warning"):
        assert needle in text, needle


def test_run_log_without_quiet_console_still_writes_the_file(tmp_path):
    from nerfify_ns.runlog import run_log

    with run_log(tmp_path / "nerfify.log"):
        logging.getLogger("nerfify.test").info("a stage started")
    assert "a stage started" in (tmp_path / "nerfify.log").read_text()
    assert not any(getattr(h, "baseFilename", None) == str(tmp_path / "nerfify.log")
                   for h in logging.getLogger().handlers)  # the handler is gone after the block
