#!/usr/bin/env bash
# Demo without hardware: a simulated RD2100 (fake_gyro) on a pseudo-terminal, gyro_node
# compensating its frames, and imu_echo printing the compensated yaw rate in deg/s.
# Runs for DEMO_SECONDS (default 60) or until Ctrl-C. SERIAL picks the gyro (default NAVC3545).
# The simulated gyro stays still until the node reports its startup static bias, then turns;
# a refused (or missing) startup bias ends the demo with exit 1.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh

SERIAL=${SERIAL:-NAVC3545}
DEMO_SECONDS=${DEMO_SECONDS:-60}
# Loopback discovery in a domain of its own: the demo does not mix with other ROS 2 traffic.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-42}

dir=$(mktemp -d)
link=$dir/rd2100
pids=()
cleanup() {
    # SIGTERM: background jobs of a script ignore SIGINT; all three programs stop cleanly on SIGTERM.
    for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
    for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
    rm -rf "$dir"
}
trap cleanup EXIT

# The simulated gyro: still until SIGUSR1, then +30, 0, -45, 0 deg/s for 6 s each, repeating.
.venv/bin/python - "$SERIAL" "$link" <<'PY' >/dev/null &
import signal, sys, threading
from art_gyro_calibration.fake_gyro import FakeGyro, RateProfile
turn, done = threading.Event(), threading.Event()
signal.signal(signal.SIGUSR1, lambda *_: turn.set())
signal.signal(signal.SIGTERM, lambda *_: done.set())
with FakeGyro(sys.argv[1], link=sys.argv[2], profile='0', seed=1) as fake:
    while not (turn.wait(0.2) or done.is_set()):
        pass
    # The profile runs on the fake's clock (period 24 s): rotate it so the turn starts now.
    segments, phase = [(6.0, 30.0), (6.0, 0.0), (6.0, -45.0), (6.0, 0.0)], (fake.sent / fake.rate_hz) % 24.0
    rotated, at = [], 0.0
    for d, r in segments:   # before the phase: the end of the profile
        if (o := min(at + d, 24.0) - max(at, 24.0 - phase)) > 1e-9:
            rotated.append((o, r))
        at += d
    left = 24.0 - phase
    for d, r in segments:   # from the phase: the profile from its start
        if min(d, left) > 1e-9:
            rotated.append((min(d, left), r))
        left -= d
    fake.simulator.profile = RateProfile(tuple(rotated))
    done.wait()
PY
pids+=($!)
# The link appears once the fake is up; a fake that exited (an unknown SERIAL, say) has said why.
until [[ -e $link ]]; do
    kill -0 "${pids[0]}" 2>/dev/null || { echo "demo: the simulated gyro did not start" >&2; exit 1; }
    sleep 0.1
done

.venv/bin/gyro_node --ros-args -p serial_number:="$SERIAL" -p port:="$link" &
pids+=($!)

echo "demo: fake $SERIAL on $link, still; waiting for the node's startup static bias (100 frames = 10 s)" >&2
if ! .venv/bin/imu_echo --wait-static-bias --timeout 60; then
    echo "demo: the startup static bias was refused or never came: stopping" >&2
    exit 1
fi
kill -USR1 "${pids[0]}"
echo "demo: turning at +30, 0, -45, 0 deg/s (6 s each, repeating)" >&2
timeout "$DEMO_SECONDS" .venv/bin/imu_echo --every 5 || true
