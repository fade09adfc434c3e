"""The report's heavy imports are done ahead, on a thread, while the take is filmed; a module that
cannot be imported is no error there (the report meets it where it is used)."""
import subprocess
import sys


def test_warm_imports_loads_what_it_can_and_never_raises():
    code = ("import sys, threading\n"
            "from cinetransfer.transfer import REPORT_IMPORTS, warm_imports\n"
            "assert 'cvxpy' not in sys.modules\n"
            "t = threading.Thread(target=warm_imports, args=(('cvxpy', 'no_such_module_here', 'json'),))\n"
            "t.start(); t.join()\n"
            "assert 'cvxpy' in sys.modules and 'no_such_module_here' not in sys.modules\n"
            "assert 'cvxpy' in REPORT_IMPORTS\n"
            # the figures are drawn in the figure process, which imports matplotlib's figure modules
            "assert not any(m.startswith('matplotlib') for m in REPORT_IMPORTS)\n"
            "from cinetransfer.report.workers import WARM\n"
            "assert {'matplotlib.figure', 'matplotlib.backends.backend_agg'} <= set(WARM)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
