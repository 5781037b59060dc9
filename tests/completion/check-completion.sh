#!/usr/bin/env bash
# The bash completion of markerctl and markerd as a shell meets it: each
# script parses (bash -n), loads in a clean bash and registers a function
# for its program (complete -p), and that function, called as bash calls it
# on TAB (COMP_WORDS, COMP_CWORD), offers
#   - after `markerctl` and after each command that has some, exactly the
#     commands its --help lists;
#   - after `--`, every long option that the command's --help lists and no
#     other (but its parent's, which CLI11 takes after the command too);
#     after `-`, every short one;
#   - for an option whose --help gives its choices ({a,b,c}), exactly those;
#   - files where a command takes them (detect's images, sweep's plans,
#     report's run directories, --config's TOML files, markerd's --config),
#     and "-" after a typed "-" where a command reads standard input.
#
#   check-completion.sh --markerctl PROGRAM --markerd PROGRAM --scripts DIR
set -uo pipefail

here=$(dirname "$(realpath "$0")")
# shellcheck source=SCRIPTDIR/../support/cli_help.sh
source "$here/../support/cli_help.sh"

markerctl='' markerd='' scripts=''
while [[ $# -gt 0 ]]; do
  case $1 in
    --markerctl) markerctl=$(realpath "$2"); shift 2 ;;
    --markerd) markerd=$(realpath "$2"); shift 2 ;;
    --scripts) scripts=$(realpath "$2"); shift 2 ;;
    *) echo "check-completion: unknown argument $1" >&2; exit 2 ;;
  esac
done
[[ -x $markerctl && -x $markerd && -d $scripts ]] ||
  { echo "usage: check-completion.sh --markerctl PROGRAM --markerd PROGRAM --scripts DIR" >&2; exit 2; }

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
export CLI_HELP_CACHE=$work/help
mkdir "$CLI_HELP_CACHE"

failed=0
fail() {
  echo "check-completion: FAIL: $*"
  failed=1
}

# What TAB offers after WORD... (the last word is the one being completed,
# "" for a new one), one a line, sorted: the script is sourced into a bash
# without startup files, and the function is the one `complete -p` names.
complete_words() {  # SCRIPT WORD...
  bash --norc --noprofile -c '
    source "$1" || exit 3
    shift
    COMP_WORDS=("$@")
    COMP_CWORD=$((${#COMP_WORDS[@]} - 1))
    COMP_LINE="$*"
    COMP_POINT=${#COMP_LINE}
    function=$(complete -p "$1" 2>/dev/null | sed -n "s/.* -F \([^ ]*\) .*/\1/p")
    [[ -n $function ]] || { echo "no completion function registered for $1" >&2; exit 4; }
    "$function" "$1" "${COMP_WORDS[COMP_CWORD]}" "${COMP_WORDS[COMP_CWORD - 1]}" || exit 5
    printf "%s\n" "${COMPREPLY[@]}"
  ' _ "$@" | sed '/^$/d' | sort -u
}

# SET differs from EXPECTED: the words missing and the words too many.
differ() {  # WHAT EXPECTED OFFERED
  local missing extra
  missing=$(comm -23 <(sort -u <<<"$2" | sed '/^$/d') <(sed '/^$/d' <<<"$3") | tr '\n' ' ')
  extra=$(comm -13 <(sort -u <<<"$2" | sed '/^$/d') <(sed '/^$/d' <<<"$3") | tr '\n' ' ')
  [[ -z $missing ]] || fail "$1: not offered: $missing"
  [[ -z $extra ]] || fail "$1: offered but not in --help: $extra"
}

markerctl_script=$scripts/markerctl.bash
markerd_script=$scripts/markerd.bash
for script in "$markerctl_script" "$markerd_script"; do
  [[ -f $script ]] || { fail "no script $script"; continue; }
  errors=$(bash -n "$script" 2>&1) || fail "bash -n $script: $errors"
done
[[ $failed -eq 0 ]] || exit 1

commands=$(cli_help_commands "$markerctl") || { fail "cannot list markerctl's commands"; exit 1; }
[[ $(wc -l <<<"$commands") -ge 5 ]] || fail "markerctl --help lists only: $commands"

# "" is markerctl itself.
while IFS= read -r command; do
  read -ra words <<<"$command"
  shown="markerctl${command:+ $command}"

  subcommands=$(cli_help_subcommands "$markerctl" "${words[@]}") || { fail "cannot read '$shown --help'"; continue; }
  offered=$(complete_words "$markerctl_script" markerctl "${words[@]}" "")
  if [[ -n $subcommands ]]; then
    differ "'$shown <TAB>'" "$subcommands" "$offered"
  fi

  long=$(cli_help_long_options "$markerctl" "${words[@]}") || { fail "cannot read '$shown --help'"; continue; }
  parent=""
  if [[ ${#words[@]} -ge 2 ]]; then
    parent=$(cli_help_long_options "$markerctl" "${words[@]:0:${#words[@]}-1}")
  fi
  offered=$(complete_words "$markerctl_script" markerctl "${words[@]}" "--")
  # Every option of the command; beyond them only its parent's.
  differ "'$shown --<TAB>'" "$long" "$(comm -23 <(sed '/^$/d' <<<"$offered") <(comm -23 <(sort -u <<<"$parent" | sed '/^$/d') <(sort -u <<<"$long")))"

  short=$(cli_help_options "$markerctl" "${words[@]}" | grep -v '^--')
  offered=$(complete_words "$markerctl_script" markerctl "${words[@]}" "-")
  missing=$(comm -23 <(sed '/^$/d' <<<"$short") <(sed '/^$/d' <<<"$offered") | tr '\n' ' ')
  [[ -z $missing ]] || fail "'$shown -<TAB>': not offered: $missing"

  # Options with their choices in the help: "--axis rail|turntable:{rail,turntable}".
  while read -r option choices; do
    [[ -n $option ]] || continue
    offered=$(complete_words "$markerctl_script" markerctl "${words[@]}" "$option" "")
    differ "'$shown $option <TAB>'" "$(tr ',' '\n' <<<"$choices")" "$offered"
  done < <(cli_help_text "$markerctl" "${words[@]}" | sed -n 's/^  \(-[^ ]*,\)\?\(--[^ ]*\) [^ ]*:{\([^}]*\)}.*/\2 \3/p')
done < <(printf '\n%s\n' "$commands")

# Files, in a directory of our own.
mkdir "$work/files" "$work/files/run1" "$work/files/run2"
touch "$work/files/plan.toml" "$work/files/frame.png" "$work/files/notes.txt"
cd "$work/files" || exit 1
expect() {  # WHAT EXPECTED(space-separated) SCRIPT WORD...
  local what=$1 expected=$2
  shift 2
  differ "$what" "$(tr ' ' '\n' <<<"$expected")" "$(complete_words "$@")"
}
expect "'markerctl sweep start <TAB>' (plans)" "plan.toml run1 run2" "$markerctl_script" markerctl sweep start ""
expect "'markerctl rig --config <TAB>'" "plan.toml run1 run2" "$markerctl_script" markerctl rig --config ""
expect "'markerctl detect <TAB>' (images)" "frame.png notes.txt plan.toml run1 run2" \
  "$markerctl_script" markerctl detect --family frame8 ""
expect "'markerctl report <TAB>' (run directories)" "run1 run2" "$markerctl_script" markerctl report run1 ""
expect "'markerctl report --paper <TAB>'" "run1 run2" "$markerctl_script" markerctl report --paper ""
expect "'markerctl render --frame=s<TAB>'" "socket switch" "$markerctl_script" markerctl render --frame=s
# '-' (standard input) after a typed "-" where a command reads a file, with
# the options; not where none is read.
for command in "detect" "sweep check" "sweep start" "call rig.move"; do
  read -ra words <<<"$command"
  complete_words "$markerctl_script" markerctl "${words[@]}" - | grep -qx -- - ||
    fail "'markerctl $command -<TAB>': not offered: - (standard input)"
done
! complete_words "$markerctl_script" markerctl marker - | grep -qx -- - ||
  fail "'markerctl marker -<TAB>': offered - (standard input), which marker does not read"
expect "'markerd --config <TAB>'" "plan.toml run1 run2" "$markerd_script" markerd --config ""
expect "'markerd -c p<TAB>'" "plan.toml" "$markerd_script" markerd -c p

# markerd's options.
long=$(cli_help_long_options "$markerd") || fail "cannot read 'markerd --help'"
differ "'markerd --<TAB>'" "$long" "$(complete_words "$markerd_script" markerd "--")"
short=$(cli_help_options "$markerd" | grep -v '^--')
missing=$(comm -23 <(sed '/^$/d' <<<"$short") <(complete_words "$markerd_script" markerd "-") | tr '\n' ' ')
[[ -z $missing ]] || fail "'markerd -<TAB>': not offered: $missing"

[[ $failed -eq 0 ]] || exit 1
echo "check-completion: markerctl's $(wc -l <<<"$commands") commands and markerd complete as their --help says"
