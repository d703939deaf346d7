"""zenoh specifics: frames through a router between two client processes, the shared session, the
config file, and the command-line flags every zenoh-speaking command takes."""

from __future__ import annotations

import argparse
import json
import select
import subprocess
import sys
import textwrap
import time

import pytest

from link.transports import open_transport
from link.transports.base import free_loopback_port
from link.transports.zenoh_session import (
    ZenohSettings,
    add_zenoh_arguments,
    session_users,
    shared_session,
    zenoh_options_from_args,
)
from model.errors import UserError

# The far end, in its own process: a client of the router that sends every frame back reversed
# (so an answer cannot be our own frame looping back) until it receives b"stop".
ECHO_CLIENT = textwrap.dedent("""
    import sys
    from link.transports import open_transport
    router, out_key, back_key = sys.argv[1:4]
    with open_transport("zenoh:" + router, mode="client", tx=back_key, rx=out_key) as end:
        if not end.wait_for_subscribers(10.0):
            sys.exit("echo: nobody subscribes to " + back_key)
        print("ready", flush=True)
        while True:
            for frame in end.receive(1.0):
                if frame == b"stop":
                    sys.exit(0)
                end.send(frame[::-1])
""")


def wait_for_line(process: subprocess.Popen, timeout_s: float) -> str:
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    return process.stdout.readline() if ready else ""


def receive_frames(transport, count: int, timeout_s: float) -> list[bytes]:
    frames, deadline = [], time.monotonic() + timeout_s
    while len(frames) < count and time.monotonic() < deadline:
        frames.extend(transport.receive(0.05))
    return frames


def test_frames_cross_a_router_between_two_clients_both_ways(zenoh_router):
    out_key, back_key = "test/router/out", "test/router/back"
    with open_transport(f"zenoh:{zenoh_router.endpoint}", mode="client", tx=out_key, rx=back_key) as ours:
        echo = subprocess.Popen([sys.executable, "-c", ECHO_CLIENT, zenoh_router.endpoint, out_key, back_key],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert wait_for_line(echo, 15.0).strip() == "ready", echo.stderr.read() if echo.poll() else ""
            assert ours.wait_for_subscribers(5.0)
            frames = [bytes(range(size)) for size in (1, 60, 255)] + [b"\xfd" + bytes(279)]
            for frame in frames:
                assert ours.send(frame)
            assert receive_frames(ours, len(frames), 5.0) == [frame[::-1] for frame in frames]

            # Clients never connect to each other: without the router, nothing gets through.
            zenoh_router.process.terminate()
            zenoh_router.process.wait(5.0)
            ours.send(b"anyone there?")
            assert receive_frames(ours, 1, 0.5) == []
        finally:
            echo.kill()
            echo.wait(5.0)


def test_transports_with_the_same_settings_share_one_reference_counted_session():
    settings = ZenohSettings.from_options("")
    assert session_users(settings) == 0
    with open_transport("zenoh", tx="test/share/ab", rx="test/share/ba") as a:
        with open_transport("zenoh", tx="test/share/ba", rx="test/share/ab") as b:
            assert session_users(settings) == 2 and a._session is b._session
            assert a.wait_for_subscribers(2.0)
            a.send(b"ping")
            assert b.receive(2.0) == [b"ping"]  # in-process transports meet in their session
        assert session_users(settings) == 1
        with shared_session(settings) as session:
            assert session is a._session and session_users(settings) == 2
    assert session_users(settings) == 0


def test_config_file_is_used_and_explicit_options_override_it(tmp_path, free_tcp_port):
    file_port, flag_port = free_tcp_port(), free_tcp_port()
    config = tmp_path / "zenoh.json5"
    config.write_text(textwrap.dedent(f"""
        // a zenoh config file, JSON5 with comments, as zenoh's own tools read it
        {{
          mode: "router",
          listen: {{ endpoints: ["tcp/127.0.0.1:{file_port}"] }},
          scouting: {{ multicast: {{ enabled: false }}, delay: 0 }},
        }}
    """))
    from_file = ZenohSettings.from_options(config_file=str(config)).to_config()
    assert json.loads(from_file.get_json("mode")) == "router"
    assert json.loads(from_file.get_json("listen/endpoints")) == [f"tcp/127.0.0.1:{file_port}"]
    overridden = ZenohSettings.from_options(config_file=str(config), mode="peer",
                                            listen=[f"tcp/127.0.0.1:{flag_port}"]).to_config()
    assert json.loads(overridden.get_json("mode")) == "peer"
    assert json.loads(overridden.get_json("listen/endpoints")) == [f"tcp/127.0.0.1:{flag_port}"]

    # And for real: a session from the file listens where the file says.
    with open_transport("zenoh", tx="test/file/ab", rx="test/file/ba", config_file=str(config)) as a, \
            open_transport(f"zenoh:tcp/127.0.0.1:{file_port}", tx="test/file/ba", rx="test/file/ab",
                           listen=[]) as b:
        assert b.wait_for_subscribers(5.0)
        b.send(b"via the file's endpoint")
        assert a.receive(2.0) == [b"via the file's endpoint"]


def test_unreadable_config_file_is_a_one_line_user_error(tmp_path):
    config = tmp_path / "broken.json5"
    config.write_text("{ mode: ")
    with pytest.raises(UserError, match="broken.json5") as caught:
        open_transport("zenoh", tx="a", config_file=str(config))
    assert "\n" not in str(caught.value)


def test_unknown_or_unreachable_router_is_a_one_line_user_error(free_tcp_port):
    with pytest.raises(UserError, match="cannot open zenoh session") as caught:
        open_transport(f"zenoh:tcp/127.0.0.1:{free_tcp_port()}", mode="client", tx="a")
    assert "\n" not in str(caught.value)


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="test")
    add_zenoh_arguments(parser)
    return parser


def test_zenoh_flags_become_transport_options():
    args = make_parser().parse_args([
        "--mode", "client", "--connect", "tcp/10.0.0.1:7447", "--connect", "udp/10.0.0.2:7447",
        "--listen", "tcp/0.0.0.0:7448", "--config", "site.json5", "--scouting"])
    assert zenoh_options_from_args(args) == {
        "mode": "client", "connect": ["tcp/10.0.0.1:7447", "udp/10.0.0.2:7447"],
        "listen": ["tcp/0.0.0.0:7448"], "config_file": "site.json5", "scouting": True}


def test_no_zenoh_flags_means_no_options_so_defaults_apply():
    options = zenoh_options_from_args(make_parser().parse_args([]))
    assert options == {}
    config = ZenohSettings.from_options(**options).to_config()
    assert json.loads(config.get_json("mode")) == "peer"
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False


def test_no_scouting_flag_turns_a_config_files_scouting_off():
    assert zenoh_options_from_args(make_parser().parse_args(["--no-scouting"])) == {"scouting": False}


@pytest.mark.parametrize("argv", [["--connect", "nonsense"], ["--mode", "satellite"], ["--listen", "7447"]])
def test_bad_zenoh_flag_is_an_argparse_error(argv, capsys):
    with pytest.raises(SystemExit) as exited:
        make_parser().parse_args(argv)
    assert exited.value.code == 2
    assert argv[1] in capsys.readouterr().err


# A ground station started before its emulator listens (`fly` starts both at once, a user may start the
# ground station first): zenoh's own retry comes 1 s after the failed first try, ours 20, 60, 140, 300 ms after.
LISTENER_LATE_S = 0.15
ZENOH_DEFAULT_FIRST_RETRY_S = 1.0


def test_a_session_connecting_before_its_far_end_listens_meets_it_soon_after_it_does():
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    with open_transport(f"zenoh:{endpoint}", tx="test/retry/early", rx="test/retry/late") as early:
        time.sleep(LISTENER_LATE_S)
        with open_transport("zenoh", listen=[endpoint], tx="test/retry/late", rx="test/retry/early"):
            listening = time.monotonic()
            assert early.wait_for_subscribers(10.0)
            met_after_s = time.monotonic() - listening
    # zenoh's default schedule would meet ZENOH_DEFAULT_FIRST_RETRY_S - LISTENER_LATE_S (0.85 s) after
    assert met_after_s < 0.6
