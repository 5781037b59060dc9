#!/usr/bin/env bash
# Renders each man page as man-db does for a reader (man -l), with groff's
# warnings on, and fails on any diagnostic: an undefined macro, an unknown
# escape or glyph, a line that cannot be broken. Also checks the NAME line
# that mandb indexes for whatis(1) and apropos(1) (lexgrog), and that the
# page's section matches its file name. mandoc -T lint runs too where
# mandoc is installed (it is not a dependency).
#
#   check-render.sh PAGE...
#
# Exit status 0 when every page is clean, 1 otherwise (the reasons on
# stdout, one "FAIL:" line per page).
set -uo pipefail

[[ $# -ge 1 ]] || { echo "usage: check-render.sh PAGE..." >&2; exit 2; }
for tool in man groff lexgrog; do
  command -v $tool >/dev/null ||
    { echo "check-render: FAIL: $tool not found: it comes with Debian's man-db and groff-base (tools/install-deps.sh)"; exit 1; }
done

failed=0
fail() {
  echo "check-render: FAIL: $*"
  failed=1
}

for page in "$@"; do
  name=$(basename "$page")
  [[ -f $page ]] || { fail "$page: no such file"; continue; }

  # As lintian renders pages: the whole page through man-db's pipeline to
  # groff's intermediate output, warnings on, at a fixed width. man exits 0
  # on warnings, so its standard error is the verdict.
  warnings=$(LC_ALL=C.UTF-8 MANROFFSEQ='' MANWIDTH=80 man --warnings -E UTF-8 -l -Tutf8 -Z "$page" 2>&1 >/dev/null)
  [[ -z $warnings ]] || fail "$name: man --warnings:"$'\n'"$warnings"

  # What a reader sees must not be empty (a page that groff swallows whole,
  # say after an unclosed diversion, renders without a warning).
  lines=$(MANWIDTH=80 man -l "$page" 2>/dev/null | wc -l)
  [[ $lines -ge 20 ]] || fail "$name: man -l renders only $lines lines"

  # .TH NAME SECTION, and the section is the file's extension.
  th=$(sed -n 's/^\.TH[[:space:]]\+\([^[:space:]]\+\)[[:space:]]\+\([^[:space:]]\+\).*/\1 \2/p' "$page" | head -1)
  expected="$(tr '[:lower:]' '[:upper:]' <<<"${name%.*}") ${name##*.}"
  [[ $th == "$expected" ]] || fail "$name: .TH says '$th', the file name '$expected'"

  # whatis(1) and apropos(1) index the NAME line: "name \- what it is".
  whatis=$(lexgrog "$page" 2>&1) || fail "$name: lexgrog finds no NAME line: $whatis"
  [[ $whatis == *"\"${name%.*} - "* ]] || fail "$name: the NAME line is not '${name%.*} \\- ...': $whatis"

  if command -v mandoc >/dev/null; then
    lint=$(mandoc -T lint -W warning "$page" 2>&1) || fail "$name: mandoc -T lint:"$'\n'"$lint"
  fi
done

[[ $failed -eq 0 ]] || exit 1
echo "check-render: $# pages render without warnings"
