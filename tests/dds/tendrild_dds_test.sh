#!/usr/bin/env bash
# tendrild over DDS, end to end: a sanitized tendrild with its simulated catheter, and
# tendril-dds-probe as the only other DDS participant (loopback only, a domain of this test's own).
# Checks that joint states and the operating state arrive over DDS, that a command without the lease
# is refused (409 lease_held) and leaves the robot where it was, that one with the lease enables and
# moves the simulated robot, that wrong sizes and non-finite values are refused like their REST
# twins, that a flood is cut by the rate limit, and that /metrics counts all of it.
# usage: tendrild_dds_test.sh <tendrild> <tendril-dds-probe>
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
tendrild="$1"
probe="$2"
# shellcheck source=../api/server.sh
source "$here/../api/server.sh"
trap stop_tendrild EXIT

export CYCLONEDDS_URI="file://$here/loopback.xml"
domain=$((100 + $$ % 120))
export TENDRILD_ARGS="--config {config} --dds-domain $domain"
failures=0
ok() { echo "ok - $*"; }
not_ok() { echo "not ok - $*"; failures=$((failures + 1)); }
p() { "$probe" --domain "$domain" "$@"; }
rest() {  # METHOD PATH [BODY]
  curl -sS -X "$1" -H "Authorization: Bearer $TENDRIL_TOKEN" -H 'Content-Type: application/json' \
    ${3:+--data "$3"} "$TENDRIL_URL$2"
}
field() { node -e 'const v=JSON.parse(process.argv[1]);console.log(eval("v"+process.argv[2]))' "$1" "$2"; }

start_tendrild "$tendrild" || exit 1
grep -q "tendrild: dds: domain $domain" "$TENDRIL_LOG" && ok "tendrild joined DDS domain $domain" ||
  not_ok "tendrild did not say it joined DDS domain $domain"

# 1. State arrives over DDS.
js="$(p --timeout 20 echo srmc joint_states --count 5)"
if [ "$(printf '%s\n' "$js" | grep -c '"position"')" = 5 ] &&
   [ "$(field "$(printf '%s\n' "$js" | tail -n 1)" '.name.length')" = 4 ]; then
  ok "5 joint states of 4 joints on rt/srmc/joint_states"
else
  not_ok "joint states over DDS: $js"
fi
os="$(p --timeout 10 echo srmc operating_state)"
[ "$(field "$os" '.state')" = DISABLED ] && ok "operating state DISABLED on rt/srmc/operating_state" ||
  not_ok "operating state over DDS: $os"
pose="$(p --timeout 10 echo srmc measured_cp)"
[ "$(field "$pose" '.orientation.length')" = 4 ] && ok "tip pose on rt/srmc/measured_cp" ||
  not_ok "tip pose over DDS: $pose"
shape="$(p --timeout 10 echo srmc backbone)"
# The catheter's backbone in metres: points from the base to the tip, the last one at the tip pose.
if [ "$(field "$shape" '.positions_m.length >= 10')" = true ] &&
   [ "$(field "$shape" '.positions_m.every((p) => p.every((v) => Math.abs(v) < 1))')" = true ] &&
   [ "$(field "$shape" '.first_orientation.length')" = 4 ]; then
  ok "backbone on rt/srmc/backbone ($(field "$shape" '.positions_m.length') poses, metres)"
else
  not_ok "backbone over DDS: ${shape:0:400}"
fi
# The vessel map, written once at start (transient-local): this subscriber comes later and still gets it.
map="$(p --timeout 10 echo maps vessel)"
if [ "$(field "$map" '.width > 100 && v.point_step === 12 && v.data_bytes === v.width * 12')" = true ] &&
   [ "$(field "$map" '.fields.map((f) => f.name + f.offset + ":" + f.datatype).join()')" = "x0:7,y4:7,z8:7" ] &&
   [ "$(field "$map" '.frame_id')" = world ] &&
   [ "$(field "$map" '.bounds.max_m[2] - v.bounds.min_m[2] > 0.01 && v.bounds.max_m[2] < 1')" = true ]; then
  ok "vessel map on rt/maps/vessel ($(field "$map" '.width') points, x y z float32 in metres, frame world)"
else
  not_ok "vessel map over DDS: ${map:0:400}"
fi

# 2. Without the lease: refused, nothing moves.
out="$(p --timeout 10 send srmc state_command enable --client no-lease)"
status=$?
if [ $status = 1 ] && [ "$(field "$out" '.status')" = 409 ] && [ "$(field "$out" '.code')" = lease_held ]; then
  ok "state_command without the lease: 409 lease_held"
else
  not_ok "state_command without the lease answered (exit $status): $out"
fi
os="$(p --timeout 10 echo srmc operating_state)"
[ "$(field "$os" '.state')" = DISABLED ] && ok "the refused enable left the robot DISABLED" ||
  not_ok "after the refused enable: $os"

# 3. With the lease (taken over REST, its token in the samples): enable, then move.
lease="$(rest POST /api/v1/lease '{}')"
token="$(field "$lease" '.lease_token')"
[ -n "$token" ] && [ "$token" != undefined ] || { not_ok "no lease token: $lease"; exit 1; }
out="$(p --timeout 10 send srmc state_command enable --lease "$token" --client operator)"
[ $? = 0 ] && [ "$(field "$out" '.status')" = 200 ] && ok "state_command enable with the lease: 200" ||
  not_ok "enable with the lease: $out"
for _ in $(seq 100); do
  os="$(p --timeout 5 echo srmc operating_state)"
  [ "$(field "$os" '.state')" = ENABLED ] && break
  sleep 0.1
done
[ "$(field "$os" '.state')" = ENABLED ] && ok "the robot is ENABLED (seen over DDS)" || not_ok "not enabled: $os"

robots="$(rest GET /api/v1/robots)"
# A goal a quarter into each joint's range (as tests/api/rest.test.mjs), and the tolerance 2 % of it.
goal="$(node -e 'const r=JSON.parse(process.argv[1])[0];
  console.log(r.joints.map(j=>(j.lower+(j.upper-j.lower)*0.25).toFixed(3)).join(","))' "$robots")"
before="$(p --timeout 5 echo srmc joint_states)"
out="$(p --timeout 10 send srmc move_jp "$goal" --client no-lease)"
[ $? = 1 ] && [ "$(field "$out" '.code')" = lease_held ] && ok "move_jp without the lease: 409 lease_held" ||
  not_ok "move_jp without the lease: $out"
sleep 1
after="$(p --timeout 5 echo srmc joint_states)"
node -e 'const [a,b]=[JSON.parse(process.argv[1]),JSON.parse(process.argv[2])];
  process.exit(a.position.every((v,i)=>Math.abs(v-b.position[i])<1e-3)?0:1)' "$before" "$after" &&
  ok "the refused move_jp moved nothing" || not_ok "the robot moved after a refused move_jp: $before -> $after"

out="$(p --timeout 10 send srmc move_jp "$goal" --lease "$token" --client operator)"
[ $? = 0 ] && [ "$(field "$out" '.status')" = 202 ] && ok "move_jp with the lease: 202" ||
  not_ok "move_jp with the lease: $out"
reached=0
for _ in $(seq 150); do
  js="$(p --timeout 5 echo srmc joint_states)"
  if node -e 'const m=JSON.parse(process.argv[1]);const r=JSON.parse(process.argv[2])[0];
      const g=process.argv[3].split(",").map(Number);
      process.exit(m.position.every((v,i)=>Math.abs(v-g[i])<=0.02*(r.joints[i].upper-r.joints[i].lower))?0:1)' \
      "$js" "$robots" "$goal"; then
    reached=1
    break
  fi
  sleep 0.1
done
[ $reached = 1 ] && ok "the simulated robot reached the DDS goal $goal (joint states over DDS)" ||
  not_ok "the robot did not reach $goal: $js"

# 4. Bad samples: refused as REST refuses them.
out="$(p --timeout 10 send srmc servo_jv 0,0 --lease "$token" --client operator)"
[ "$(field "$out" '.status')" = 422 ] && [ "$(field "$out" '.code')" = wrong_size ] &&
  ok "servo_jv with 2 values: 422 wrong_size" || not_ok "servo_jv with 2 values: $out"
out="$(p --timeout 10 send srmc servo_jv nan,0,0,0 --lease "$token" --client operator)"
[ "$(field "$out" '.status')" = 422 ] && [ "$(field "$out" '.code')" = not_finite ] &&
  ok "servo_jv with NaN: 422 not_finite" || not_ok "servo_jv with NaN: $out"
out="$(p --timeout 10 send srmc move_jp inf,0,0,0 --lease "$token" --client operator)"
[ "$(field "$out" '.status')" = 422 ] && ok "move_jp with inf: 422" || not_ok "move_jp with inf: $out"
os="$(p --timeout 5 echo srmc operating_state)"
[ "$(field "$os" '.state')" = ENABLED ] && ok "bad samples left the robot ENABLED" || not_ok "after bad samples: $os"

# 5. A flood (no lease: nothing may move) is cut by the rate limit (burst 50, 200/s); what the
# reader's keep-last history overwrote is counted from the gaps in request_id.
flood="$(p --timeout 30 send srmc servo_jv 0,0,0,0 --count 1500 --rate 0 --client flood 2>&1)"
if grep -q '"code":"rate_limited"' <<< "$flood"; then
  ok "a flood of 1500 samples: $(printf '%s\n' "$flood" | tail -n 1 | sed 's/^tendril-dds-probe: //')"
else
  not_ok "no sample of the flood was rate-limited: $(printf '%s\n' "$flood" | tail -n 1)"
fi

# 6. /metrics counts it all.
metrics="$(rest GET /metrics)"
for pattern in 'tendril_dds_commands_refused_total{code="lease_held"} [1-9]' \
               'tendril_dds_commands_refused_total{code="rate_limited"} [1-9]' \
               'tendril_dds_commands_refused_total{code="not_finite"} [1-9]' \
               'tendril_dds_commands_total{status="202"} 1$' \
               'tendril_dds_samples_published_total{kind="state"} [1-9]' \
               'tendril_dds_commands_lost_total [0-9]'; do
  grep -q "$pattern" <<< "$metrics" && ok "/metrics: $pattern" || not_ok "/metrics lacks $pattern"
done
# Every command sample is accounted for: taken by the bridge and answered (1500 of the flood and the
# 7 before it), or counted lost from the gaps in its writer's request_id. (The probe itself may miss
# answers of a flood: the result writer keeps the newest 64, as every command reader does.) The probe
# returns once its samples are acknowledged, which is before the bridge has taken the newest of them
# from its reader; a gap is counted only when the sample after it is taken. So /metrics is read until
# the count is complete, for at most 10 s (a bound on a stuck bridge, not a speed assertion); a run
# read 263 taken + 1061 lost right after the probe returned.
for _ in $(seq 100); do
  taken="$(printf '%s\n' "$metrics" | sed -n 's/^tendril_dds_commands_total{status="[0-9]*"} \([0-9]*\)$/\1/p' |
    awk '{ s += $1 } END { print s + 0 }')"
  lost="$(printf '%s\n' "$metrics" | sed -n 's/^tendril_dds_commands_lost_total \([0-9]*\)$/\1/p')"
  [ $((taken + lost)) -ge 1507 ] && break
  sleep 0.1
  metrics="$(rest GET /metrics)"
done
[ $((taken + lost)) = 1507 ] && ok "every sample counted: $taken taken + $lost lost = 7 + 1500 sent" ||
  not_ok "samples counted: $taken taken + $lost lost != 7 + 1500 sent"
printf '%s\n' "$metrics" | grep '^tendril_dds_' | sed 's/^/# /'

check_clean_shutdown || failures=$((failures + 1))
echo "$failures failed"
[ $failures = 0 ]
