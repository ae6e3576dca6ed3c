#!/usr/bin/env bash
# The services of docker/compose.yaml as native processes on 127.0.0.1, without Docker:
#   PostgreSQL (a throwaway cluster), the Prefect server (API + UI) on it, an S3 endpoint (moto's server,
#   bucket `fleet`), a Dask scheduler and two workers, a Prefect process work pool `bagport` and its worker.
#
#   bash scripts/stack.sh up       # start everything on free ports; writes $BAGPORT_STACK_DIR/stack.env
#   source .stack/stack.env        # PREFECT_API_URL, AWS_*, BAGPORT_DASK_ADDRESS, ... for the CLI and tests
#   bash scripts/stack.sh status   # each service, its pid, alive or not
#   bash scripts/stack.sh down     # stops exactly the processes `up` started (by pid), removes the cluster
#
# State lives in $BAGPORT_STACK_DIR (default: .stack in the work tree): pids, logs, the env file, data.
set -Eeuo pipefail
REPO="$(cd "$(dirname "$0")/.." && pwd)"
STACK_DIR="${BAGPORT_STACK_DIR:-$REPO/.stack}"
PIDS="$STACK_DIR/pids"
ENV_FILE="$STACK_DIR/stack.env"
PY="$REPO/.venv/bin/python"
BIN="$REPO/.venv/bin"
S3_KEY=bagport
S3_SECRET=bagport-secret

log() { echo "stack: $*" >&2; }

free_port() { "$PY" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

# Wait until a command succeeds; fail with the service's log after $2 seconds.
wait_for() {
  local what="$1" timeout_s="$2" logfile="$3"
  shift 3
  local deadline=$((SECONDS + timeout_s))
  until "$@" >/dev/null 2>&1; do
    if ((SECONDS > deadline)); then
      log "$what did not come up within ${timeout_s} s; last lines of $logfile:"
      tail -n 30 "$logfile" >&2 || true
      return 1
    fi
    sleep 0.5
  done
}

http_ok() { "$PY" -c 'import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=2)' "$1"; }

# Start a service in its own session (so `down` can signal its whole process group) and record its pid.
start() {
  local name="$1"
  shift
  setsid "$@" >"$STACK_DIR/logs/$name.log" 2>&1 </dev/null &
  echo "$name $!" >>"$PIDS"
}

as_pg_owner() {
  if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}

start_postgres() {
  local port="$1" pgbin pgdata
  pgbin="$(dirname "$(bash "$REPO/scripts/setup_stack.sh" --print-initdb)")"
  pgdata="$STACK_DIR/pg"
  if [ "$(id -u)" = 0 ]; then
    # initdb and postgres refuse to run as root: the cluster belongs to the `postgres` system user, and
    # must sit where that user can reach it (a pytest tmp dir is private to root).
    if ! runuser -u postgres -- test -x "$STACK_DIR"; then
      pgdata="$(mktemp -d /tmp/bagport-stack-pg.XXXXXX)"
    fi
    mkdir -p "$pgdata"
    chown postgres: "$pgdata"
  fi
  echo "$pgdata" >"$STACK_DIR/pgdata"
  as_pg_owner "$pgbin/initdb" -D "$pgdata" -U prefect --auth=trust --encoding=UTF8 --no-sync \
    >"$STACK_DIR/logs/initdb.log" 2>&1
  as_pg_owner "$pgbin/pg_ctl" -D "$pgdata" -l "$pgdata/server.log" -w -t 60 \
    -o "-h 127.0.0.1 -p $port -k $pgdata -c fsync=off" start >"$STACK_DIR/logs/postgres.log" 2>&1
  echo "postgres $(head -n 1 "$pgdata/postmaster.pid")" >>"$PIDS"
  as_pg_owner "$pgbin/createdb" -h 127.0.0.1 -p "$port" -U prefect prefect
}

cmd_up() {
  if [ -s "$PIDS" ]; then
    log "already up ($PIDS exists); run: bash scripts/stack.sh down"
    exit 1
  fi
  bash "$REPO/scripts/setup_stack.sh"
  mkdir -p "$STACK_DIR/logs" "$STACK_DIR/prefect-home"
  : >"$PIDS"
  trap 'log "up failed; stopping what was started"; cmd_down; exit 1' ERR
  local pg_port api_port s3_port dask_port
  pg_port="$(free_port)"; api_port="$(free_port)"; s3_port="$(free_port)"; dask_port="$(free_port)"
  cat >"$ENV_FILE" <<EOF
# written by scripts/stack.sh up: source it before the CLI or prefect commands
export BAGPORT_STACK_DIR="$STACK_DIR"
export BAGPORT_REPO="$REPO"
export PREFECT_HOME="$STACK_DIR/prefect-home"
export PREFECT_API_URL="http://127.0.0.1:$api_port/api"
export PREFECT_UI_URL="http://127.0.0.1:$api_port"
export PREFECT_SERVER_ANALYTICS_ENABLED=false
export AWS_ENDPOINT_URL="http://127.0.0.1:$s3_port"
export AWS_ACCESS_KEY_ID="$S3_KEY"
export AWS_SECRET_ACCESS_KEY="$S3_SECRET"
export AWS_DEFAULT_REGION=us-east-1
export BAGPORT_DASK_ADDRESS="tcp://127.0.0.1:$dask_port"
export BAGPORT_DATABASE_URL="postgresql+asyncpg://prefect:prefect@127.0.0.1:$pg_port/prefect"
EOF
  # shellcheck source=/dev/null
  source "$ENV_FILE"
  export HF_HUB_OFFLINE=1 PREFECT_LOGGING_LEVEL="${PREFECT_LOGGING_LEVEL:-INFO}"

  log "postgres on 127.0.0.1:$pg_port"
  start_postgres "$pg_port"
  log "prefect server on $PREFECT_UI_URL"
  # months of hourly runs: Prefect's vacuum deletes flow runs (with their task runs, logs and artifacts)
  # that ended more than 90 days ago, and old events; bagport reads none of them back
  PREFECT_SERVER_DATABASE_CONNECTION_URL="$BAGPORT_DATABASE_URL" PREFECT_UI_API_URL="$PREFECT_API_URL" \
    PREFECT_SERVER_SERVICES_DB_VACUUM_ENABLED="${PREFECT_SERVER_SERVICES_DB_VACUUM_ENABLED:-events,flow_runs}" \
    start prefect-server "$BIN/prefect" server start --host 127.0.0.1 --port "$api_port"
  log "S3 (moto) on $AWS_ENDPOINT_URL"
  start s3 "$BIN/moto_server" -H 127.0.0.1 -p "$s3_port"
  log "dask scheduler on $BAGPORT_DASK_ADDRESS"
  start dask-scheduler "$BIN/dask" scheduler --host 127.0.0.1 --port "$dask_port" --no-dashboard
  wait_for "S3 endpoint" 60 "$STACK_DIR/logs/s3.log" http_ok "$AWS_ENDPOINT_URL/moto-api/"
  "$PY" -c 'import s3fs; s3fs.S3FileSystem().mkdir("fleet")'
  for i in 1 2; do
    (cd "$REPO" && start "dask-worker-$i" "$BIN/dask" worker "$BAGPORT_DASK_ADDRESS" --nthreads 1 \
      --memory-limit 4GiB --no-dashboard --name "worker-$i")
  done
  wait_for "prefect server" 180 "$STACK_DIR/logs/prefect-server.log" http_ok "$PREFECT_API_URL/health"
  "$BIN/prefect" --no-prompt work-pool create bagport --type process --overwrite >/dev/null
  (cd "$REPO" && start prefect-worker "$BIN/prefect" worker start --pool bagport --type process)
  wait_for "dask workers" 120 "$STACK_DIR/logs/dask-worker-1.log" "$PY" -c \
    'import sys; from distributed import Client; Client(sys.argv[1], timeout=5).wait_for_workers(2, timeout=5)' \
    "$BAGPORT_DASK_ADDRESS"
  wait_for "prefect worker" 120 "$STACK_DIR/logs/prefect-worker.log" "$PY" -c \
    'import json, sys, urllib.request as u; r = u.Request(sys.argv[1] + "/work_pools/bagport/workers/filter", b"{}", {"Content-Type": "application/json"}); sys.exit(not json.load(u.urlopen(r)))' \
    "$PREFECT_API_URL"
  trap - ERR
  log "up; source $ENV_FILE"
}

alive() { kill -0 "$1" 2>/dev/null; }
# a process left in the service's process group (its children), after the service itself exited
group_alive() { pgrep -g "$1" >/dev/null 2>&1; }

cmd_down() {
  [ -f "$PIDS" ] || { log "not up (no $PIDS)"; return 0; }
  local name pid pgdata=""
  [ -f "$STACK_DIR/pgdata" ] && pgdata="$(cat "$STACK_DIR/pgdata")"
  # one at a time in reverse start order: each worker stops while what it talks to still answers
  tac "$PIDS" | while read -r name pid; do
    case "$name" in
      postgres) kill -INT "$pid" 2>/dev/null || true ;;  # SIGINT is PostgreSQL's fast shutdown
      # Prefect 3.8.8's worker forwards SIGTERM/SIGINT to itself and never exits: it only polls the
      # server, and its flow-run processes are in its process group, so the group is killed outright.
      prefect-worker) kill -KILL -- "-$pid" 2>/dev/null || true ;;
      *) kill -TERM -- "-$pid" 2>/dev/null || kill -TERM "$pid" 2>/dev/null || true ;;
    esac
    deadline=$((SECONDS + 10))
    while { alive "$pid" || group_alive "$pid"; } && ((SECONDS < deadline)); do sleep 0.2; done
    if alive "$pid" || group_alive "$pid"; then
      log "$name ($pid) did not stop within 10 s; killing its process group"
      kill -KILL -- "-$pid" 2>/dev/null || kill -KILL "$pid" 2>/dev/null || true
    fi
  done
  if [ -n "$pgdata" ] && [ "$pgdata" != "$STACK_DIR/pg" ]; then rm -rf "$pgdata"; fi
  rm -rf "$STACK_DIR/pg" "$STACK_DIR/pgdata" "$PIDS" "$ENV_FILE"
  log "down"
}

cmd_status() {
  [ -f "$PIDS" ] || { echo "stack: not up"; return 1; }
  local name pid down=0
  while read -r name pid; do
    if alive "$pid"; then echo "$name $pid running"; else echo "$name $pid STOPPED"; down=1; fi
  done <"$PIDS"
  [ -f "$ENV_FILE" ] && echo "env: source $ENV_FILE"
  return "$down"
}

case "${1:-}" in
  up) cmd_up ;;
  down) cmd_down ;;
  status) cmd_status ;;
  *) echo "usage: scripts/stack.sh up|down|status (state in \$BAGPORT_STACK_DIR, default .stack)" >&2; exit 2 ;;
esac
