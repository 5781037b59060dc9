# Sourced by the tests of the man pages and of the shell completion: what a
# program's CLI11 --help says it takes, so that those tests compare against
# the programs themselves rather than a list kept beside them.
#
#   cli_help_long_options PROGRAM [WORD...]   long options of PROGRAM WORD... --help, one a line
#   cli_help_options PROGRAM [WORD...]        the same with the short ones (-o), one a line
#   cli_help_subcommands PROGRAM [WORD...]    its subcommands, one a line
#   cli_help_commands PROGRAM                 every command path, nested ones too ("rig move"), one a line
#
# A --help that fails, or prints no "Options:" section, is an error: the
# format has changed and the callers would otherwise compare against nothing.
# With CLI_HELP_CACHE naming a directory, each help is run once and kept
# there (a test asks for the same command's help several times).

# The help of PROGRAM WORD...; fails loudly when there is none.
cli_help_text() {
  local text cached=""
  if [[ -n ${CLI_HELP_CACHE-} ]]; then
    cached=$CLI_HELP_CACHE/$(printf '%s\0' "$@" | md5sum | cut -d' ' -f1)
    if [[ -f $cached ]]; then
      cat "$cached"
      return 0
    fi
  fi
  if ! text=$("$@" --help 2>&1); then
    echo "cli_help: '$* --help' failed: $text" >&2
    return 1
  fi
  if ! grep -q '^Options:$' <<<"$text"; then
    echo "cli_help: '$* --help' printed no 'Options:' section (has CLI11's help format changed?)" >&2
    return 1
  fi
  [[ -z $cached ]] || printf '%s\n' "$text" >"$cached"
  printf '%s\n' "$text"
}

# The lines of one section ("Options:", "Subcommands:"), up to the blank line
# that ends it; an entry's name is the first word of a line indented by two.
cli_help_section() {  # SECTION
  awk -v section="$1" '$0 == section { on = 1; next } on && /^$/ { exit } on && /^  [^ ]/ { print $1 }'
}

cli_help_options() {
  local text
  text=$(cli_help_text "$@") || return 1
  cli_help_section "Options:" <<<"$text" | tr ',' '\n' | grep '^-' | sort -u
}

cli_help_long_options() {
  local options
  options=$(cli_help_options "$@") || return 1
  grep '^--' <<<"$options" || true
}

cli_help_subcommands() {
  local text
  text=$(cli_help_text "$@") || return 1
  cli_help_section "Subcommands:" <<<"$text"
}

cli_help_commands() {  # PROGRAM [WORD...]
  local command subcommands
  subcommands=$(cli_help_subcommands "$@") || return 1
  for command in $subcommands; do
    printf '%s\n' "${*:2}${2:+ }$command"
    cli_help_commands "$@" "$command" || return 1
  done
}
