#!/usr/bin/env bash
# The durable-queue tests (tests/durable.rs) against a real PostgreSQL
# server instead of SQLite: a throwaway cluster from Debian's `postgresql`
# on a private port, a fresh database per test, removed at the end.
#   scripts/postgres-check.sh            # installs postgresql if missing (root)
# The log is what the issue's closing note quotes.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
    apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q postgresql
fi
bin=$(ls -d /usr/lib/postgresql/*/bin | sort -V | tail -1)
dir=$(mktemp -d /tmp/sylva-pg.XXXXXX)
port=${SYLVA_PG_PORT:-54329}
# initdb refuses root: the cluster runs as `postgres` when we are root.
as() { if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi; }
[ "$(id -u)" = 0 ] && chown postgres "$dir"
as "$bin/initdb" -D "$dir/data" -A trust -U sylva >/dev/null
as "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w \
    -o "-k $dir -p $port -c listen_addresses=127.0.0.1" start
trap 'as "$bin/pg_ctl" -D "$dir/data" -m fast stop >/dev/null; rm -rf "$dir"' EXIT
as "$bin/postgres" --version
# The workspace's build, as scripts/test.sh made it: `-p sylva` alone
# unifies features differently and rebuilt dependencies (2.5 min).
cargo build --tests --locked --workspace
for t in a_coordinator_killed_mid_sequence_resumes_it_and_every_frame_is_the_same \
         a_frame_cut_into_strips_keeps_the_strips_done_before_a_kill; do
    db="sylva_$(date +%s%N)"
    as "$bin/psql" -h 127.0.0.1 -p "$port" -U sylva -d postgres -qc "CREATE DATABASE $db"
    echo "== $t on postgres://sylva@127.0.0.1:$port/$db"
    SYLVA_TEST_DATABASE_URL="postgres://sylva@127.0.0.1:$port/$db" \
        cargo test --locked --workspace --test tests "durable::$t" -- --exact --nocapture 2>&1 \
        | grep -v ' WARN ' || exit 1
    echo "-- what the database holds after it:"
    as "$bin/psql" -h 127.0.0.1 -p "$port" -U sylva -d "$db" -c \
        "SELECT id, state, frames, frames_done, result_bytes FROM jobs ORDER BY seq" \
        -c "SELECT version, name FROM schema_migrations"
done
echo "postgres-check: passed"
