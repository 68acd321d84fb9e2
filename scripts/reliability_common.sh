# Sourced by scripts/soak.sh and scripts/inventory.sh: a private ROS master for one run, so runs
# do not meet other masters (or each other) on the default port.
# shellcheck shell=bash

# es_start_master [PORT]: starts roscore, waits until it answers, sets ROS_MASTER_URI and
# ES_MASTER_PID. The port defaults to a random one in 11400..11899.
es_start_master() {
  local port="${1:-$((11400 + RANDOM % 500))}"
  export ROS_MASTER_URI="http://localhost:$port"
  export ROS_HOSTNAME=localhost
  mkdir -p "$ROS_LOG_DIR"
  roscore -p "$port" > "$ROS_LOG_DIR/roscore_$port.log" 2>&1 &
  ES_MASTER_PID=$!
  local i
  for i in $(seq 1 100); do
    if rosparam get /run_id > /dev/null 2>&1; then
      # rosout must be up too: the driver reads the node's messages from /rosout_agg.
      rosnode list 2>/dev/null | grep -q '^/rosout$' && return 0
    fi
    sleep 0.2
  done
  echo "[reliability] roscore on port $port did not start (log: $ROS_LOG_DIR/roscore_$port.log)" >&2
  return 1
}

# es_stop_master: stops the roscore started above (by its pid, and its children).
es_stop_master() {
  if [ -n "${ES_MASTER_PID:-}" ] && kill -0 "$ES_MASTER_PID" 2>/dev/null; then
    kill -INT "$ES_MASTER_PID" 2>/dev/null || true
    local i
    for i in $(seq 1 50); do
      kill -0 "$ES_MASTER_PID" 2>/dev/null || break
      sleep 0.2
    done
    kill -9 "$ES_MASTER_PID" 2>/dev/null || true
  fi
  ES_MASTER_PID=
}
