#!/usr/bin/env bash
# One-way DDS latency of tendril's joint states between two hosts made of network namespaces (a veth
# pair; Cyclone DDS bound to it with unicast discovery, as tests/dds/netns_test.sh), beside Cyclone's
# own ddsperf ping/pong between the same namespaces in the same run. Host A publishes, host B
# subscribes with tendril-dds-latency, which times each sample on arrival against the writer's DDS
# source time stamp (transport) and the state's own header stamp (age); the namespaces share the
# machine's clock, so both are one-way times. Four streams, one after the other:
#   1. tendrild as shipped: its DDS bridge publishes at publish_rate_hz = 50
#   2. tendrild with publish_rate_hz = 1000 (the control loop's rate; the largest the config accepts)
#   3. tendril-dds-latency pub: a synthetic 1 kHz JointState stream through the bridge's own writer
#      function (write_joint_state), same type, QoS and sample size, without tendrild
#   4. ddsperf ping (best effort, 1 kHz, the same sample size) against ddsperf pong: RTT/2
# Prints a table and the load average before and after. Reports speed; asserts none: it fails only
# when a stream does not arrive. Needs root and iproute2 (exit 77 otherwise). In scripts/test.sh --full.
# usage: dds_latency.sh <tendrild> <tendril-dds-latency> [seconds per stream, default 10]
set -uo pipefail
tendrild="$(realpath "$1")"
latency="$(realpath "$2")"
seconds="${3:-${TENDRIL_DDS_BENCH_SECONDS:-10}}"
warmup=2
repo_root="$(cd "$(dirname "$0")/../.." && pwd)"
if [ "$(id -u)" != 0 ] || ! command -v ip >/dev/null; then
  echo "skipped: needs root and iproute2 (ip netns)"
  exit 77
fi
ddsperf="$(command -v ddsperf || true)"
[ -n "$ddsperf" ] || echo "note: ddsperf not found (Debian package cyclonedds-tools); its row is left out"
n=$(($$ % 200 + 20))
a="tendril-lat-a-$$"
b="tendril-lat-b-$$"
work="$(mktemp -d /tmp/tendril-dds-latency.XXXXXX)"
pids=()
stop() {  # PID: SIGTERM, then SIGKILL after 5 s (a ddsperf pong was seen to hang on its way out)
  if kill -0 "$1" 2>/dev/null; then
    kill -TERM "$1" 2>/dev/null
    for _ in $(seq 50); do kill -0 "$1" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$1" 2>/dev/null
  fi
  wait "$1" 2>/dev/null
}
cleanup() {
  for pid in "${pids[@]}"; do stop "$pid"; done
  ip netns del "$a" 2>/dev/null
  ip netns del "$b" 2>/dev/null
  [ -z "${KEEP_NETNS_LOG:-}" ] && rm -rf "$work"
}
trap cleanup EXIT
if ! ip netns add "$a" 2>"$work/err" || ! ip netns add "$b" 2>>"$work/err"; then
  echo "skipped: cannot make network namespaces here: $(cat "$work/err")"
  exit 77
fi
ip link add "tlA$n" type veth peer name "tlB$n" || { echo "skipped: cannot make a veth pair"; exit 77; }
ip link set "tlA$n" netns "$a"
ip link set "tlB$n" netns "$b"
ip -n "$a" addr add "10.78.$n.1/24" dev "tlA$n"
ip -n "$b" addr add "10.78.$n.2/24" dev "tlB$n"
for ns in "$a" "$b"; do ip -n "$ns" link set lo up; done
ip -n "$a" link set "tlA$n" up
ip -n "$b" link set "tlB$n" up

cyclone_config() {  # INTERFACE PEER
  cat <<XML
<CycloneDDS xmlns="https://cdds.io/config"><Domain id="any">
  <General><Interfaces><NetworkInterface name="$1"/></Interfaces><AllowMulticast>false</AllowMulticast></General>
  <Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>
    <Peers><Peer address="$2"/></Peers></Discovery>
</Domain></CycloneDDS>
XML
}
cyclone_config "tlA$n" "10.78.$n.2" > "$work/a.xml"
cyclone_config "tlB$n" "10.78.$n.1" > "$work/b.xml"
# Programs in host B run in the foreground; those in host A in the background as
# (... exec ip netns exec ...) &, so that $! is the program itself (ip netns exec execs it) and can be
# stopped.
in_b() { CYCLONEDDS_URI="file://$work/b.xml" ip netns exec "$b" "$@"; }
domain=$((n % 200 + 1))

# The catheter as shipped but in free space (as tests/api/server.sh), no imaging.
node -e '
  const fs = require("fs");
  const robot = JSON.parse(fs.readFileSync(process.argv[1], "utf8"));
  if (robot.catheter && robot.catheter.simulation) delete robot.catheter.simulation.vessel;
  fs.writeFileSync(process.argv[2], JSON.stringify(robot, null, 2));
' "$repo_root/config/robots/srmc.json" "$work/srmc.json"
token="bench-$(od -An -N8 -tx1 /dev/urandom | tr -d ' \n')"

failures=0
load() { cut -d' ' -f1-3 /proc/loadavg; }
echo "load average before: $(load) ($(nproc) cores); $seconds s per stream after a ${warmup} s warm-up"

# Runs tendrild in host A with the bridge publishing at RATE Hz and measures rt/srmc/joint_states in B.
tendrild_stream() {  # LABEL RATE
  local label=$1 rate=$2
  cat > "$work/server.json" <<JSON
{"listen": "127.0.0.1:8080", "token": "$token", "control_rate_hz": 1000, "publish_rate_hz": $rate,
 "realtime_priority": true, "robots": ["$work/srmc.json"]}
JSON
  (cd "$repo_root" && TENDRIL_TOKEN="$token" CYCLONEDDS_URI="file://$work/a.xml" \
    exec ip netns exec "$a" "$tendrild" --config "$work/server.json" --dds-domain "$domain") \
    > "$work/tendrild-$rate.log" 2>&1 &
  local pid=$!
  pids+=("$pid")
  for _ in $(seq 150); do
    grep -q "tendrild: dds: domain $domain" "$work/tendrild-$rate.log" && break
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.2
  done
  if in_b "$latency" --domain "$domain" --timeout 30 sub srmc --seconds "$seconds" --warmup "$warmup" \
       > "$work/$label.json" 2> "$work/$label.err"; then
    echo "ok - $label: $(cat "$work/$label.json")"
  else
    echo "not ok - $label: $(tail -n 3 "$work/$label.err"); tendrild: $(tail -n 3 "$work/tendrild-$rate.log")"
    failures=$((failures + 1))
  fi
  stop "$pid"
}

tendrild_stream tendrild-50 50
tendrild_stream tendrild-1000 1000

# The synthetic 1 kHz stream: the publisher runs until the subscriber has its window.
(CYCLONEDDS_URI="file://$work/a.xml" exec ip netns exec "$a" "$latency" --domain "$domain" --timeout 30 \
  pub srmc --rate 1000 --seconds $((seconds + warmup + 4))) > "$work/pub.json" 2> "$work/pub.err" &
pub_pid=$!
pids+=("$pub_pid")
if in_b "$latency" --domain "$domain" --timeout 30 sub srmc --seconds "$seconds" --warmup "$warmup" \
     > "$work/synthetic-1000.json" 2> "$work/synthetic-1000.err"; then
  echo "ok - synthetic-1000: $(cat "$work/synthetic-1000.json")"
else
  echo "not ok - synthetic-1000: $(tail -n 3 "$work/synthetic-1000.err")"
  failures=$((failures + 1))
fi
wait "$pub_pid"
echo "   publisher: $(cat "$work/pub.json" 2>/dev/null) $(tail -n 2 "$work/pub.err")"

# ddsperf: its KS topic (sequence number, key, octets) sized as tendril's 4-joint JointState sample
# (208 bytes of CDR: header with "srmc_base", the 4 names, 3 x 4 doubles), best effort (-u) as
# tendril's state topics; ping at 1 kHz from host B, pong in host A. It prints the round trip's
# percentiles once a second; one-way = RTT/2.
if [ -n "$ddsperf" ]; then
  (CYCLONEDDS_URI="file://$work/a.xml" exec ip netns exec "$a" "$ddsperf" -i "$domain" -u \
    -D $((seconds + warmup + 8)) pong) > "$work/pong.log" 2>&1 &
  pong_pid=$!
  pids+=("$pong_pid")
  sleep 1
  in_b "$ddsperf" -i "$domain" -u -D $((seconds + warmup + 1)) ping 1kHz size 208 > "$work/ping.log" 2>&1
  status=$?
  stop "$pong_pid"
  if [ $status = 0 ] && grep -q ' 99% ' "$work/ping.log"; then
    echo "ok - ddsperf ping/pong: $(grep -c ' 99% ' "$work/ping.log") one-second reports"
  else
    echo "not ok - ddsperf ping/pong (exit $status): $(tail -n 3 "$work/ping.log")"
    failures=$((failures + 1))
  fi
fi

echo "load average after: $(load)"
node - "$work" "$seconds" "$warmup" <<'JS'
const fs = require("fs");
const [work, seconds, warmup] = [process.argv[2], Number(process.argv[3]), Number(process.argv[4])];
const read = (f) => { try { return JSON.parse(fs.readFileSync(`${work}/${f}`, "utf8")); } catch { return null; } };
const median = (v) => { const s = [...v].sort((x, y) => x - y); return s.length ? s[Math.floor((s.length - 1) / 2)] : NaN; };
const f = (x) => (Number.isFinite(x) ? (x >= 1000 ? (x / 1000).toFixed(2) + " ms" : x.toFixed(0) + " us") : "-");
// Columns every row has alike: the median over the one-second windows of each window's p50 and p99
// (the form ddsperf reports in), the largest; then the whole run's p99 and the state's age where known.
const rows = [];
for (const [label, what] of [["tendrild-50", "tendrild, publish_rate_hz 50 (shipped)"],
                             ["tendrild-1000", "tendrild, publish_rate_hz 1000"],
                             ["synthetic-1000", "write_joint_state 1 kHz (tendril-dds-latency pub)"]]) {
  const r = read(`${label}.json`);
  if (!r) continue;
  rows.push([what, r.rate_hz.toFixed(0), r.samples, f(r.per_second_transport_us.p50_median),
             f(r.per_second_transport_us.p99_median), f(r.transport_us.max), f(r.transport_us.p99),
             `${f(r.age_us.p50)} / ${f(r.age_us.p99)}`]);
}
let ping = [];
try { ping = fs.readFileSync(`${work}/ping.log`, "utf8").split("\n").filter((l) => / 99% /.test(l)); } catch {}
if (ping.length) {
  // Per-second reports after the same warm-up as the other streams.
  const us = (l, k) => { const m = l.match(new RegExp(`${k} ([0-9.]+)us`)); return m ? Number(m[1]) : NaN; };
  const kept = ping.slice(warmup);
  const cnt = kept.reduce((s, l) => s + Number((l.match(/cnt (\d+)/) || [0, 0])[1]), 0);
  rows.push(["ddsperf ping/pong 1 kHz, RTT/2", (cnt / kept.length).toFixed(0), cnt,
             f(median(kept.map((l) => us(l, "50%"))) / 2), f(median(kept.map((l) => us(l, "99%"))) / 2),
             f(Math.max(...kept.map((l) => us(l, "max"))) / 2), "-", "-"]);
}
const head = ["stream (host A -> host B)", "rate Hz", "samples", "p50 (per s, median)", "p99 (per s, median)",
              "max", "p99 (whole run)", "state age p50 / p99"];
const table = [head, ...rows];
const widths = head.map((_, i) => Math.max(...table.map((r) => String(r[i]).length)));
console.log(`\none-way latency, ${seconds} s per stream (transport: dds_write -> reader; state age: control tick -> reader)`);
for (const r of table) console.log(r.map((c, i) => String(c).padEnd(widths[i])).join(" | "));
JS
echo "$failures failed"
[ $failures = 0 ]
