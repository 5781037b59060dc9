# bash completion for markerd (installed as
# <prefix>/share/bash-completion/completions/markerd): its options, and TOML
# files for --config. tests/completion/check-completion.sh compares the
# options with markerd --help.

_markerd() {
  local cur=${COMP_WORDS[COMP_CWORD]} prev=${COMP_WORDS[COMP_CWORD - 1]}
  COMPREPLY=()
  if [[ $prev == -c || $prev == --config ]]; then
    compopt -o filenames 2>/dev/null
    mapfile -t COMPREPLY < <(compgen -f -X '!*.toml' -- "$cur"; compgen -d -- "$cur")
    return 0
  fi
  mapfile -t COMPREPLY < <(compgen -W "-c --config --check-config --no-lock-check -h --help --version" -- "$cur")
  return 0
}

complete -F _markerd markerd
