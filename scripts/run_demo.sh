#!/usr/bin/env bash
# Demo without hardware: a simulated RD2100 (fake_rd2100) on a pseudo-terminal, gyro_node
# compensating its frames, and imu_echo printing the compensated yaw rate in deg/s.
# Runs for DEMO_SECONDS (default 60) or until Ctrl-C. SERIAL picks the gyro (default NAVC3545).
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
    # SIGTERM: background jobs of a script ignore SIGINT; both programs stop cleanly on SIGTERM.
    for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
    for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
    rm -rf "$dir"
}
trap cleanup EXIT

# Still for 12 s (the startup static bias takes 100 frames = 10 s), then turns: +30, 0, -45 deg/s.
.venv/bin/fake_rd2100 --serial "$SERIAL" --link "$link" --profile '12:0,6:30,6:0,6:-45' --seed 1 >/dev/null &
pids+=($!)
# The link appears once the fake is up; a fake that exited (an unknown SERIAL, say) has said why.
until [[ -e $link ]]; do
    kill -0 "${pids[0]}" 2>/dev/null || { echo "demo: fake_rd2100 did not start" >&2; exit 1; }
    sleep 0.1
done

.venv/bin/gyro_node --ros-args -p serial_number:="$SERIAL" -p port:="$link" &
pids+=($!)

echo "demo: fake $SERIAL on $link; true rate 0 (12 s), +30, 0, -45 deg/s (6 s each), repeating" >&2
timeout "$DEMO_SECONDS" .venv/bin/imu_echo --every 5 || true
