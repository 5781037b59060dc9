#!/usr/bin/env bash
# The man pages against the programs: every command that markerctl --help
# lists (nested ones too) has its section in markerctl(1), .SS "markerctl
# CMD", whose .TP items name every option that `markerctl CMD --help`
# prints, and no option it does not take; the same for markerd(8)'s OPTIONS
# and markerd --help, and for markerctl(1)'s OPTIONS and markerctl --help.
# A section for a command that does not exist fails too. -h/--help is left
# out of the commands' sections: every command has it, and the page says so
# once.
#
#   check-options.sh --markerctl PROGRAM --markerd PROGRAM --pages DIR
set -uo pipefail

here=$(dirname "$(realpath "$0")")
# shellcheck source=SCRIPTDIR/../support/cli_help.sh
source "$here/../support/cli_help.sh"

markerctl='' markerd='' pages=''
while [[ $# -gt 0 ]]; do
  case $1 in
    --markerctl) markerctl=$2; shift 2 ;;
    --markerd) markerd=$2; shift 2 ;;
    --pages) pages=$2; shift 2 ;;
    *) echo "check-options: unknown argument $1" >&2; exit 2 ;;
  esac
done
[[ -x $markerctl && -x $markerd && -d $pages ]] ||
  { echo "usage: check-options.sh --markerctl PROGRAM --markerd PROGRAM --pages DIR" >&2; exit 2; }

CLI_HELP_CACHE=$(mktemp -d)
export CLI_HELP_CACHE
trap 'rm -rf "$CLI_HELP_CACHE"' EXIT

failed=0
fail() {
  echo "check-options: FAIL: $*"
  failed=1
}

# The options named by the .TP items of one section of a page: KIND is SH
# or SS, HEADING the section's title. Font escapes and \- are undone; an
# item's options are its words that begin with a dash.
page_options() {  # PAGE KIND HEADING
  awk -v kind=".$2" -v heading="$3" '
    /^\.S[HS] / {
      title = $0; sub(/^\.S[HS] +/, "", title); gsub(/"/, "", title)
      on = ($1 == kind && title == heading); next
    }
    on && /^\.TP/ { tag = 1; next }
    on && tag {
      tag = 0; line = $0
      sub(/^\.[A-Z]+ */, "", line)
      gsub(/\\f[BIRP]/, "", line); gsub(/\\-/, "-", line); gsub(/\\&|\\%|"/, "", line)
      n = split(line, words, /[ ,|\[\]]+/)
      for (i = 1; i <= n; i++) if (words[i] ~ /^--?[A-Za-z]/) { w = words[i]; sub(/=.*/, "", w); print w }
    }' "$1" | sort -u
}

# The headings of a page's .SS sections that begin with PREFIX.
page_sections() {  # PAGE PREFIX
  sed -n 's/^\.SS "\?\('"$2"'[^"]*\)"\?$/\1/p' "$1"
}

# The options PROGRAM WORD... takes against those the section documents.
compare() {  # PAGE KIND HEADING SKIP_HELP PROGRAM [WORD...]
  local page=$1 kind=$2 heading=$3 skip_help=$4
  shift 4
  local taken documented call
  call="$(basename "$1")${2:+ }${*:2} --help"
  taken=$(cli_help_options "$@") || { fail "cannot read '$call'"; return; }
  [[ $skip_help == yes ]] && taken=$(grep -vx -e -h -e --help <<<"$taken")
  documented=$(page_options "$page" "$kind" "$heading")
  if [[ -z $documented && -n $taken ]]; then
    fail "$(basename "$page"): no .$kind \"$heading\" section with .TP items (for '$call')"
    return
  fi
  local option
  for option in $taken; do
    grep -qxF -- "$option" <<<"$documented" ||
      fail "$(basename "$page"): \"$heading\" does not document $option, which '$call' lists"
  done
  for option in $documented; do
    grep -qxF -- "$option" <<<"$taken" ||
      fail "$(basename "$page"): \"$heading\" documents $option, which '$call' does not list"
  done
}

markerctl_page=$pages/markerctl.1
markerd_page=$pages/markerd.8

compare "$markerd_page" SH OPTIONS no "$markerd"
compare "$markerctl_page" SH OPTIONS no "$markerctl"

commands=$(cli_help_commands "$markerctl") || { fail "cannot list markerctl's commands"; exit 1; }
[[ $(wc -l <<<"$commands") -ge 5 ]] || fail "markerctl --help lists only: $commands"
sections=$(page_sections "$markerctl_page" "markerctl ")
while IFS= read -r command; do
  grep -qxF -- "markerctl $command" <<<"$sections" || fail "markerctl.1: no section .SS \"markerctl $command\""
  # shellcheck disable=SC2086 # a command path is words
  compare "$markerctl_page" SS "markerctl $command" yes "$markerctl" $command
done <<<"$commands"

# Sections for commands markerctl no longer has.
while IFS= read -r heading; do
  grep -qxF -- "${heading#markerctl }" <<<"$commands" ||
    fail "markerctl.1: section \"$heading\", but markerctl has no command '${heading#markerctl }'"
done <<<"$sections"

[[ $failed -eq 0 ]] || exit 1
echo "check-options: markerd(8) and markerctl(1) document the options of markerd and of $(wc -l <<<"$commands") markerctl commands, and no others"
