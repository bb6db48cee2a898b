# Throwaway services for the tests: a PostgreSQL server and a Dask scheduler with two worker
# processes, all on localhost, stopped when the shell that started them exits.
#
#   source tools/services.sh            # in a script (.ci/run) or a shell: starts them, exports
#                                       #   HTM_TEST_PG    postgresql://htm_test@127.0.0.1:PORT/htm_test
#                                       #   PGPASSFILE     the role's password (libpq's file; never on a command line)
#                                       #   HTM_TEST_DASK  tcp://127.0.0.1:PORT (2 workers, 1 thread each)
#   bash tools/services.sh CMD ARGS...  # runs CMD with them, then stops them (make test does this)
#
# PostgreSQL: installed with apt-get when missing; initdb into a temporary folder run as the
# `postgres` system user (created if missing: the server refuses to run as root); the test role
# `htm_test` owns the database `htm_test` and can connect to nothing else.
# Needs the project's virtualenv (dask) at $HTM_VENV (default .venv).

_htm_svc_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
HTM_VENV="${HTM_VENV:-$_htm_svc_root/.venv}"

_htm_free_port() {
    "$HTM_VENV/bin/python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

_htm_pg_bin() {
    local d
    for d in "$(dirname "$(command -v initdb 2>/dev/null || echo /nonexistent/x)")" /usr/lib/postgresql/*/bin; do
        if [ -x "$d/initdb" ] && [ -x "$d/pg_ctl" ] && [ -x "$d/postgres" ]; then
            echo "$d"
            return 0
        fi
    done
    return 1
}

htm_services_stop() {
    if [ -n "${_HTM_DASK_PIDS:-}" ]; then
        # shellcheck disable=SC2086
        kill $_HTM_DASK_PIDS 2>/dev/null || true
        local i
        for i in 1 2 3 4 5 6 7 8 9 10; do
            # shellcheck disable=SC2086
            kill -0 $_HTM_DASK_PIDS 2>/dev/null || break
            sleep 0.5
        done
        # shellcheck disable=SC2086
        kill -9 $_HTM_DASK_PIDS 2>/dev/null || true
        _HTM_DASK_PIDS=""
    fi
    if [ -n "${_HTM_PG_DATA:-}" ] && [ -d "$_HTM_PG_DATA" ]; then
        $_HTM_AS_PG "$_HTM_PG_BIN/pg_ctl" -D "$_HTM_PG_DATA" -m immediate -w stop >/dev/null 2>&1 || true
        _HTM_PG_DATA=""
    fi
    if [ -n "${HTM_SERVICES_DIR:-}" ] && [ -d "$HTM_SERVICES_DIR" ]; then
        rm -rf "$HTM_SERVICES_DIR"
    fi
    unset HTM_TEST_PG HTM_TEST_DASK PGPASSFILE HTM_SERVICES_DIR
}

_htm_start_postgres() {
    _HTM_PG_BIN="$(_htm_pg_bin)" || {
        echo "services: installing PostgreSQL (apt-get)" >&2
        (apt-get update -qq && apt-get install -y -qq postgresql) >/dev/null 2>&1 ||
            sudo -n apt-get install -y -qq postgresql >/dev/null 2>&1 || true
        _HTM_PG_BIN="$(_htm_pg_bin)" || { echo "services: PostgreSQL is not installed and apt-get could not install it" >&2; return 1; }
    }
    _HTM_AS_PG=""
    local owner
    owner="$(id -un)"
    if [ "$(id -u)" = 0 ]; then
        id postgres >/dev/null 2>&1 || useradd --system --no-create-home --shell /usr/sbin/nologin postgres
        _HTM_AS_PG="runuser -u postgres --"
        owner=postgres
    fi
    local pgdir="$HTM_SERVICES_DIR/pg" port password
    mkdir -p "$pgdir"
    chown "$owner" "$pgdir"
    chmod 700 "$pgdir"
    _HTM_PG_DATA="$pgdir/data"
    port="$(_htm_free_port)"
    # local socket (in the 0700 folder above) trusted for the admin; TCP needs a password
    $_HTM_AS_PG "$_HTM_PG_BIN/initdb" -D "$_HTM_PG_DATA" --auth-local=trust --auth-host=scram-sha-256 \
        -E UTF8 --locale=C.UTF-8 >"$pgdir/initdb.log" 2>&1 || { cat "$pgdir/initdb.log" >&2; return 1; }
    $_HTM_AS_PG "$_HTM_PG_BIN/pg_ctl" -D "$_HTM_PG_DATA" -l "$pgdir/server.log" -w -t 60 \
        -o "-p $port -k $pgdir -c listen_addresses=127.0.0.1 -c max_connections=50 -c fsync=off" start >/dev/null ||
        { cat "$pgdir/server.log" >&2; return 1; }
    password="$("$HTM_VENV/bin/python" -c 'import secrets; print(secrets.token_hex(16))')"
    # the SQL (with the password) goes through stdin, never a command line
    local psql="$_HTM_PG_BIN/psql"
    [ -x "$psql" ] || psql="psql"
    $_HTM_AS_PG "$psql" -q -v ON_ERROR_STOP=1 -h "$pgdir" -p "$port" -d postgres >/dev/null <<SQL || return 1
CREATE ROLE htm_test LOGIN NOSUPERUSER NOCREATEDB NOCREATEROLE PASSWORD '$password';
CREATE DATABASE htm_test OWNER htm_test;
REVOKE CONNECT ON DATABASE postgres FROM PUBLIC;
REVOKE CONNECT ON DATABASE template1 FROM PUBLIC;
SQL
    printf '127.0.0.1:%s:htm_test:htm_test:%s\n' "$port" "$password" >"$HTM_SERVICES_DIR/pgpass"
    chmod 600 "$HTM_SERVICES_DIR/pgpass"
    export PGPASSFILE="$HTM_SERVICES_DIR/pgpass"
    export HTM_TEST_PG="postgresql://htm_test@127.0.0.1:$port/htm_test"
}

_htm_start_dask() {
    local port dir="$HTM_SERVICES_DIR/dask"
    mkdir -p "$dir"
    port="$(_htm_free_port)"
    "$HTM_VENV/bin/dask" scheduler --host 127.0.0.1 --port "$port" --no-dashboard >"$dir/scheduler.log" 2>&1 &
    _HTM_DASK_PIDS="$!"
    disown "$!"
    export HTM_TEST_DASK="tcp://127.0.0.1:$port"
    # two worker processes, one thread each, under one nanny process that restarts a killed worker
    "$HTM_VENV/bin/dask" worker "$HTM_TEST_DASK" --nworkers 2 --nthreads 1 --no-dashboard --host 127.0.0.1 \
        --local-directory "$dir" --memory-limit 4GiB >"$dir/workers.log" 2>&1 &
    _HTM_DASK_PIDS="$_HTM_DASK_PIDS $!"
    disown "$!"
    "$HTM_VENV/bin/python" - "$HTM_TEST_DASK" <<'PY' || { tail -20 "$dir/scheduler.log" "$dir/workers.log" >&2; return 1; }
import sys, time
from distributed import Client
t0 = time.time()
while True:
    try:
        with Client(sys.argv[1], timeout="5s") as c:
            c.wait_for_workers(2, timeout=90)
            break
    except OSError:
        if time.time() - t0 > 60:
            raise
        time.sleep(0.5)
PY
}

htm_services_start() {
    HTM_SERVICES_DIR="$(mktemp -d /tmp/htm-services.XXXXXX)"
    export HTM_SERVICES_DIR
    chmod 755 "$HTM_SERVICES_DIR"
    _htm_start_postgres || { htm_services_stop; return 1; }
    _htm_start_dask || { htm_services_stop; return 1; }
    echo "services: PostgreSQL $HTM_TEST_PG, Dask $HTM_TEST_DASK (2 workers)" >&2
}

if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    # run as a script: start, run the command, stop
    set -euo pipefail
    trap htm_services_stop EXIT
    htm_services_start
    "$@"
else
    trap htm_services_stop EXIT
    htm_services_start
fi
