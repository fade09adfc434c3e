"""Every bad input a user can give the command line: one clear line on stderr, a documented exit
code, no traceback, and nothing left behind. Real `cinetransfer` processes."""
import subprocess

import pytest

from cinetransfer.shared.zenoh_config import free_tcp_port
from conftest import cli, mount_tmpfs


def one_line_error(r: subprocess.CompletedProcess, rc: int, *words: str) -> str:
    assert r.returncode == rc, (r.returncode, r.stdout[-1000:], r.stderr[-2000:])
    assert "Traceback" not in r.stderr + r.stdout, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("cinetransfer"), r.stderr
    for w in words:
        assert w in last, (w, last)
    return last


def test_a_bare_command_fails_with_the_usage():
    r = cli()
    assert r.returncode == 2 and "usage: cinetransfer COMMAND" in r.stderr


@pytest.mark.parametrize("args, words", [
    (("deploy", "up", "local", "--run-dir", "/proc/x"), ("/proc/x",)),
    (("deploy", "certs", "/proc/x"), ("/proc/x",)),
])
def test_unwritable_folders_are_one_line(tmp_path, args, words):
    r = cli(*args, env={"CT_STATE_DIR": str(tmp_path / "state")})
    one_line_error(r, 1, *words)
    assert len(r.stderr.strip().splitlines()) <= 2, r.stderr  # (deploy may say what it was doing first)


@pytest.mark.parametrize("args, words", [
    (("planner", "--rig", "bad/rig"), ("invalid rig name 'bad/rig'",)),
    (("replay", "run.mcap", "--speed", "-1"), ("--speed", ">= 0")),
])
def test_bad_flags_are_usage_errors(args, words):
    one_line_error(cli(*args), 2, *words)


def test_deploy_help_shows_only_public_commands():
    r = cli("deploy", "--help")
    assert r.returncode == 0 and "SUPPRESS" not in r.stdout and "_supervise" not in r.stdout


def test_monitor_without_a_running_deployment_says_so_in_one_line():
    r = cli("monitor", "--mode", "client", "--connect", f"tcp/127.0.0.1:{free_tcp_port()}", "--once")
    one_line_error(r, 1, "cannot use the bus", "is the deployment running")
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert ".rs:" not in r.stderr  # (not where in Zenoh's source the connection failed)


@pytest.mark.parametrize("args", [("monitor", "--deployment", "local", "--once"), ("monitor", "--once"),
                                  ("command", "planner", "stop")])
def test_tools_on_a_deployment_never_started_here_say_so_in_one_line(tmp_path, args):
    # no credentials (the deployment was never brought up with this state folder), nothing listening
    r = cli(*args, env={"CT_STATE_DIR": str(tmp_path / "state"), "CT_ROUTER_PORT": str(free_tcp_port())})
    last = one_line_error(r, 1)
    assert len(r.stderr.strip().splitlines()) == 1 and "usage:" not in r.stderr, r.stderr
    assert "is not running here" in last or "cannot use the bus" in last, last


@pytest.mark.parametrize("args", [("monitor", "--deployment", "local", "--once"), ("command", "planner", "stop")])
def test_tools_on_a_stopped_deployment_say_so_in_one_line(tmp_path, monkeypatch, args):
    from cinetransfer.deploy.config import load_config
    from cinetransfer.deploy.rundir import resolve_run_dir
    from cinetransfer.deploy.security import prepare_security

    env = {"CT_STATE_DIR": str(tmp_path / "state"), "CT_ROUTER_PORT": str(free_tcp_port()), "CT_SECRETS": ""}
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    # the credentials an earlier `deploy up local` left in its run folder; its router is gone
    cfg = load_config("local")
    run_dir = resolve_run_dir(cfg)
    run_dir.mkdir(parents=True)
    prepare_security(cfg, run_dir)
    r = cli(*args, env=env)
    one_line_error(r, 1, "cannot use the bus", "is the deployment running")
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


@pytest.fixture
def read_only_dir(tmp_path):
    """A folder nobody can write, root included (a read-only tmpfs; chmod where not root)."""
    import os

    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() != 0:
        ro.chmod(0o555)
        yield ro
        ro.chmod(0o755)
        return
    ro.rmdir()
    yield from mount_tmpfs(ro, "ro,size=1m")


@pytest.fixture
def style24(data, tmp_path_factory):
    path = tmp_path_factory.mktemp("style") / "style.json"
    r = cli("extract", str(data / "sam2_juggle_1280x720.mp4"), "--stop", "24", "-o", str(path), "--quiet")
    assert r.returncode == 0, r.stderr
    return path


@pytest.mark.parametrize("into", [".", "sub"])
def test_report_into_a_read_only_folder_is_one_line(style24, tmp_path, read_only_dir, into):
    run = tmp_path / "run"
    run.mkdir()
    (run / "style.json").write_bytes(style24.read_bytes())
    r = cli("report", str(run), "-o", str(read_only_dir / into))
    one_line_error(r, 1, "cannot write the report into", str(read_only_dir))
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_plot_into_a_read_only_folder_is_one_line(style24, read_only_dir):
    r = cli("plot", str(style24), "-o", str(read_only_dir / "style.png"))
    one_line_error(r, 1, str(read_only_dir / "style.png"))
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_style_the_camera_cannot_film_is_refused_before_anything_starts(style24, data, tmp_path):
    import json

    d = json.loads(style24.read_text())
    d["instructions"].update(fps=1000.0, frame_duration_s=0.001)  # faster than the camera films
    bad = tmp_path / "fast.json"
    bad.write_text(json.dumps(d))
    out = tmp_path / "out"
    r = cli("transfer", str(data / "sam2_juggle_1280x720.mp4"), "--style", str(bad), "-o", str(out))
    one_line_error(r, 2, "--style", "fps", "240")
    assert len(r.stderr.strip().splitlines()) == 1 and not out.exists(), r.stderr


@pytest.mark.parametrize("extra, words", [
    (("--scene", "no_such_scene"), ("no_such_scene",)),
    (("--subject", "nobody"), ("nobody",)),
    (("--rig", "bad/rig"), ("--rig", "bad/rig")),
    (("--deployment", "no_such_deployment"), ("no_such_deployment",)),
])
def test_transfer_refusals_leave_no_folder(data, tmp_path, extra, words):
    out = tmp_path / "out"
    r = cli("transfer", str(data / "sam2_juggle_1280x720.mp4"), "-o", str(out), *extra)
    one_line_error(r, 2, *words)
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not out.exists()


def test_transfer_into_a_file_is_refused(data, tmp_path):
    f = tmp_path / "a_file"
    f.write_text("keep me")
    one_line_error(cli("transfer", str(data / "sam2_juggle_1280x720.mp4"), "-o", str(f)), 2, "not a folder")
    assert f.read_text() == "keep me"


@pytest.mark.slow
def test_a_truncated_source_is_an_error_not_a_short_style(data, tmp_path):
    # the first quarter of a faststart MP4: its header still declares all 247 frames
    whole = (data / "sam2_juggle_1280x720.mp4").read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(whole[:len(whole) // 4])
    r = cli("transfer", str(cut), "-o", str(tmp_path / "out"), "--rig", "cut", "--no-eval", timeout=900)
    last = one_line_error(r, 1, "truncated or damaged", "of the 247 frames", "--max-frames")
    assert not (tmp_path / "out" / "meta.json").exists(), last  # nothing was flown
