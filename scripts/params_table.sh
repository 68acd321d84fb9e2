#!/usr/bin/env bash
# `make params-table`: writes the parameter table (src/core/pipeline/param_table.cpp, printed by
# `endo_stereo_cli --list-params --markdown`) into README.md between its params-table markers.
# test_params_io (ParamTable.TheReadmeShowsTheGeneratedTable) fails while the two differ.
set -euo pipefail
source "$(dirname "$0")/env.sh"
es_source_ws
cd "$ES_ROOT"
CLI="$WS/devel/lib/endo_stereo/endo_stereo_cli"
[ -x "$CLI" ] || { echo "params_table.sh: $CLI is not built (run: make build)" >&2; exit 1; }
table="$(mktemp)"
trap 'rm -f "$table"' EXIT
"$CLI" --list-params --markdown > "$table"
/usr/bin/python3 - "$table" README.md <<'PY'
import sys
table = open(sys.argv[1]).read()
path = sys.argv[2]
text = open(path).read()
begin, end = "<!-- params-table:begin -->\n", "<!-- params-table:end -->"
a, b = text.index(begin), text.index(end)
open(path, "w").write(text[:a + len(begin)] + table + text[b:])
print("params_table.sh: README.md's parameter table written (%d rows)" % (table.count("\n") - 2))
PY
