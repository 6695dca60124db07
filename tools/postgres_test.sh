#!/usr/bin/env bash
# make test-cluster-postgres: tests/test_cluster.py with its mlflow server's store in a private PostgreSQL
# (MLflow's production store), started here in a temp folder on 127.0.0.1 and a free port, removed after.
#
# Installs Debian's postgresql with apt-get when no initdb is found; where that cannot be done (not root, no
# apt-get, no network) it prints one line saying the test is skipped and why, and exits 0. Otherwise it exits
# with the test's code; the server is stopped and its folder removed whatever happens.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=.venv/bin/python
started=$SECONDS

skip() {
    echo "test-cluster-postgres: SKIPPED, $*"
    exit 0
}

pg_bin() {  # initdb on PATH, else Debian's newest /usr/lib/postgresql/<version>/bin (not on PATH there)
    if command -v initdb >/dev/null; then
        dirname "$(readlink -f "$(command -v initdb)")"  # a link in /usr/local/bin: the real folder has the rest
    else
        find /usr/lib/postgresql -mindepth 2 -maxdepth 2 -name bin 2>/dev/null | sort -V | tail -n 1
    fi
}

PGBIN=$(pg_bin)
if [[ -z $PGBIN || ! -x $PGBIN/initdb ]]; then
    [[ $(id -u) == 0 ]] || skip "PostgreSQL is not installed and installing it needs root (apt-get install postgresql)"
    command -v apt-get >/dev/null || skip "PostgreSQL is not installed and there is no apt-get to install it"
    echo "test-cluster-postgres: apt-get install postgresql"
    apt_log=$(mktemp)
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql; } >"$apt_log" 2>&1; then
        reason=$(grep -E -m 1 '^(E|W):' "$apt_log" || true)
        rm -f "$apt_log"
        skip "apt-get install postgresql failed (${reason:-no error line from apt-get})"
    fi
    rm -f "$apt_log"
    PGBIN=$(pg_bin)
    [[ -n $PGBIN && -x $PGBIN/initdb ]] || skip "apt-get installed postgresql but no initdb was found"
fi

# initdb refuses to run as root: the server runs as the postgres user then, in a folder it owns.
as_owner=()
if [[ $(id -u) == 0 ]]; then
    id postgres >/dev/null 2>&1 || skip "running as root and there is no postgres user to run the server"
    as_owner=(runuser -u postgres --)
fi

folder=$(mktemp -d "${TMPDIR:-/tmp}/ablate-pg.XXXXXX")
cleanup() {
    code=$?
    if [[ -f $folder/data/postmaster.pid ]]; then
        "${as_owner[@]}" "$PGBIN/pg_ctl" -D "$folder/data" -m immediate -w stop >/dev/null 2>&1 || true
    fi
    rm -rf "$folder"
    exit "$code"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
[[ ${#as_owner[@]} == 0 ]] || chown postgres: "$folder"

port=$("$PYTHON" -c 'import sys; sys.path.insert(0, "tools"); import local_cluster; print(local_cluster.free_port())')
password=$("$PYTHON" -c 'import secrets; print(secrets.token_hex(16))')
# Local (socket) connections trusted, for the setup below; TCP needs the password, as on a real server.
"${as_owner[@]}" "$PGBIN/initdb" -D "$folder/data" -U postgres -E UTF8 --locale=C.UTF-8 \
    --auth-local=trust --auth-host=scram-sha-256 >"$folder/initdb.log" 2>&1 \
    || { cat "$folder/initdb.log"; exit 1; }
# -w: pg_ctl returns once the server accepts connections (or fails, with the log to say why).
"${as_owner[@]}" "$PGBIN/pg_ctl" -D "$folder/data" -l "$folder/server.log" -w -t 120 \
    -o "-c listen_addresses=127.0.0.1 -p $port -k $folder" start >/dev/null \
    || { cat "$folder/server.log"; exit 1; }
"$PGBIN/pg_isready" -q -h 127.0.0.1 -p "$port" -t 60 || { cat "$folder/server.log"; exit 1; }
psql_admin=("$PGBIN/psql" -X -q -v ON_ERROR_STOP=1 -h "$folder" -p "$port" -U postgres)
# The password goes through psql's standard input and a password file, never a command line (ps shows those)
# nor the store's URL (the test's server and clients read it from PGPASSFILE, as the team recipe does).
"${psql_admin[@]}" <<SQL
CREATE USER mlflow PASSWORD '$password';
CREATE DATABASE mlflow OWNER mlflow;
SQL
pgpass=$folder/pgpass
(umask 077 && echo "127.0.0.1:$port:mlflow:mlflow:$password" >"$pgpass")
echo "test-cluster-postgres: PostgreSQL $("$PGBIN/postgres" --version | awk '{print $3}') on 127.0.0.1:$port" \
    "ready after $((SECONDS - started)) s"

code=0
ABLATE_CLUSTER_TESTS=1 PGPASSFILE="$pgpass" ABLATE_TEST_BACKEND="postgresql+psycopg://mlflow@127.0.0.1:$port/mlflow" \
    "$PYTHON" -m pytest -q tests/test_cluster.py || code=$?
# What the server wrote, read from PostgreSQL itself.
runs=$("${psql_admin[@]}" -d mlflow -At -c "SELECT count(*) FROM runs" 2>/dev/null) || runs="?"
metrics=$("${psql_admin[@]}" -d mlflow -At -c "SELECT count(*) FROM metrics" 2>/dev/null) || metrics="?"
echo "test-cluster-postgres: exit code $code after $((SECONDS - started)) s; PostgreSQL holds $runs runs," \
    "$metrics metric values"
exit "$code"
