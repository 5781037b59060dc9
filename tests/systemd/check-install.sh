#!/usr/bin/env bash
# Installs a build as a package would, into a staging root
# (DESTDIR=ROOT cmake --install BUILD --prefix PREFIX, for the prefixes /usr
# and /usr/local, where systemd looks), and checks what lands there: the
# binaries, the unit naming them by their installed path, the sysusers.d and
# tmpfiles.d files (applied to a scratch root by systemd-sysusers and
# systemd-tmpfiles themselves), the udev rules, the example config under
# the config directory whatever the prefix, the man pages (found by man
# under the prefix, as the unit's Documentation= names them), the bash
# completion (loaded by bash), and nothing anywhere else.
#
#   check-install.sh --cmake CMAKE --build BUILD_DIR --source SOURCE_DIR
#                    --config-dir DIR [--with-markerd]
set -euo pipefail

fail() {
  echo "check-install: FAIL: $*"
  exit 1
}

cmake=cmake build= source= config_dir= with_markerd=0
while [[ $# -gt 0 ]]; do
  case $1 in
    --cmake) cmake=$2; shift 2 ;;
    --build) build=$2; shift 2 ;;
    --source) source=$2; shift 2 ;;
    --config-dir) config_dir=$2; shift 2 ;;
    --with-markerd) with_markerd=1; shift ;;
    *) echo "check-install: unknown argument $1" >&2; exit 2 ;;
  esac
done
[[ -n $build && -n $source && $config_dir == /* ]] ||
  { echo "usage: check-install.sh --cmake CMAKE --build DIR --source DIR --config-dir /ABS [--with-markerd]" >&2; exit 2; }
here=$(dirname "$(realpath "$0")")
for tool in systemd-sysusers systemd-tmpfiles; do
  command -v $tool >/dev/null || fail "$tool not found: it comes with Debian's package systemd (tools/install-deps.sh)"
done
command -v man >/dev/null || fail "man not found: it comes with Debian's package man-db (tools/install-deps.sh)"

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# The examples cmake --install copies (systemd/install-config.cmake).
mapfile -t examples < <(cd "$source/config" && find . -type f \( -name '*.toml' -o -name '*.yaml' -o -name README.md \) |
  sed 's|^\./||' | sort)
[[ ${#examples[@]} -gt 0 ]] || fail "no example config found in $source/config"

install_into() {  # ROOT PREFIX
  if ! DESTDIR=$1 "$cmake" --install "$build" --prefix "$2" >"$work/install.log" 2>&1; then
    cat "$work/install.log"
    fail "DESTDIR=$1 cmake --install $build --prefix $2 failed (every installed target must be built first)"
  fi
}

expect_line() {  # FILE LINE
  grep -qxF -- "$2" "$1" || fail "$1 has no line '$2'"
}

check_prefix() {  # PREFIX
  local prefix=$1
  local root=$work/stage$(tr / _ <<<"$prefix")
  install_into "$root" "$prefix"

  local bin=$root$prefix/bin
  [[ -x $bin/markerctl ]] || fail "$prefix/bin/markerctl not installed"
  if [[ $with_markerd -eq 1 ]]; then
    [[ -x $bin/markerd ]] || fail "$prefix/bin/markerd not installed"
  fi

  # The unit names markerd where this install put it, not where the build
  # was configured to go.
  local unit=$root$prefix/lib/systemd/system/markerd.service
  [[ -f $unit ]] || fail "$prefix/lib/systemd/system/markerd.service not installed"
  ! grep -n '@[A-Z_]*@' "$unit" || fail "$unit has placeholders left"
  expect_line "$unit" "ExecStartPre=$prefix/bin/markerd --check-config --no-lock-check --config $config_dir/markerd.toml"
  expect_line "$unit" "ExecStart=$prefix/bin/markerd --config $config_dir/markerd.toml"
  expect_line "$unit" "Documentation=man:markerd(8) man:markerd.toml(5) man:markerctl(1) file:$prefix/share/doc/markerd/systemd.md"
  [[ -f $root$prefix/share/doc/markerd/systemd.md ]] || fail "$prefix/share/doc/markerd/systemd.md not installed"

  # The man pages where man-db looks under the prefix, each found by man as
  # the unit's Documentation= names it (man -M: the staging root's tree
  # alone), with its NAME line.
  local mandir=$root$prefix/share/man page section name
  for page in markerd.8 markerctl.1 markerd.toml.5; do
    section=${page##*.}
    cmp -s "$source/docs/man/$page" "$mandir/man$section/$page" ||
      fail "$prefix/share/man/man$section/$page missing or not docs/man/$page"
  done
  for page in $(sed -n 's/^Documentation=//p' "$unit"); do
    [[ $page =~ ^man:([^()]+)\(([0-9])\)$ ]] || continue
    name=${BASH_REMATCH[1]} section=${BASH_REMATCH[2]}
    MANWIDTH=80 man -M "$mandir" "$section" "$name" 2>/dev/null | grep -qE "^ *${name//./\\.} +- " ||
      fail "man $section $name (the unit's Documentation=) finds no page under $prefix/share/man"
  done

  # The bash completion where bash-completion loads it from, one file per
  # program, each registering its function when bash sources it.
  local completions=$root$prefix/share/bash-completion/completions program
  for program in markerctl markerd; do
    cmp -s "$source/tools/completion/$program.bash" "$completions/$program" ||
      fail "$prefix/share/bash-completion/completions/$program missing or not tools/completion/$program.bash"
    bash --norc --noprofile -c 'source "$1" && complete -p "$2"' _ "$completions/$program" "$program" >/dev/null 2>&1 ||
      fail "$prefix/share/bash-completion/completions/$program registers no completion for $program in bash"
  done
  if [[ $with_markerd -eq 1 ]]; then
    # The installed unit itself, through the same checks as the tests' copy,
    # with its programs pointed into the staging root for verify.
    mkdir -p "$work/verify"
    sed "s|=$prefix/bin/markerd |=$bin/markerd |" "$unit" >"$work/verify/markerd.service"
    "$here/check-unit.sh" "$work/verify/markerd.service" 2.5 >"$work/check-unit.log" 2>&1 ||
      { cat "$work/check-unit.log"; fail "the unit installed for prefix $prefix fails check-unit.sh"; }
  fi

  local sysusers=$root$prefix/lib/sysusers.d/markerd.conf
  local tmpfiles=$root$prefix/lib/tmpfiles.d/markerd.conf
  local rules=$root$prefix/lib/udev/rules.d/60-markerd.rules
  cmp -s "$sysusers" "$source/systemd/markerd.sysusers" || fail "$prefix/lib/sysusers.d/markerd.conf missing or not systemd/markerd.sysusers"
  cmp -s "$tmpfiles" "$source/systemd/markerd.tmpfiles" || fail "$prefix/lib/tmpfiles.d/markerd.conf missing or not systemd/markerd.tmpfiles"
  cmp -s "$rules" "$source/systemd/60-markerd.rules" || fail "$prefix/lib/udev/rules.d/60-markerd.rules missing or not systemd/60-markerd.rules"

  # The example config under the config directory, the same files as config/.
  local example
  for example in "${examples[@]}"; do
    cmp -s "$source/config/$example" "$root$config_dir/$example" || fail "$config_dir/$example not installed from config/$example"
  done
  if [[ -f $source/config/markerd.toml ]]; then
    [[ -f $root$config_dir/markerd.toml ]] || fail "$config_dir/markerd.toml, the unit's config, not installed"
  else
    echo "check-install: note: config/markerd.toml does not exist (yet), so the unit's $config_dir/markerd.toml is not installed"
  fi

  # Nothing outside the prefix and the config directory.
  local path
  while IFS= read -r path; do
    path=${path#"$root"}
    [[ $path == "$prefix"/* || $path == "$config_dir"/* ]] || fail "installed outside $prefix and $config_dir: $path"
  done < <(find "$root" ! -type d)
  echo "check-install: prefix $prefix: ok ($(find "$root" ! -type d | wc -l) files)"
}

check_prefix /usr
check_prefix /usr/local

# Installing again over an existing config keeps the rig's own files.
root=$work/stage_usr
edited=$root$config_dir/${examples[0]}
echo "# edited on the rig" >>"$edited"
cp "$edited" "$work/edited"
install_into "$root" /usr
cmp -s "$edited" "$work/edited" || fail "a second cmake --install replaced the edited $config_dir/${examples[0]}"
grep -qF "Keeping: $edited" "$work/install.log" || fail "the second cmake --install did not say it kept $edited"
echo "check-install: a second install keeps $config_dir/${examples[0]} as edited"

# The sysusers.d file, applied by systemd-sysusers to an empty root: user
# and group markerd (home: the state directory, no login shell) and group
# gpio; to a root that has a gpio group already, that group is kept.
sysusers=$work/stage_usr/usr/lib/sysusers.d/markerd.conf
sys=$work/sysroot
mkdir -p "$sys/etc"
systemd-sysusers --root="$sys" "$sysusers" || fail "systemd-sysusers rejects $sysusers"
IFS=: read -r _ _ uid gid _ home shell < <(grep '^markerd:' "$sys/etc/passwd") || fail "no user markerd after systemd-sysusers"
[[ $home == /var/lib/markerd ]] || fail "markerd's home is $home, not /var/lib/markerd"
[[ $shell == */nologin ]] || fail "markerd's shell is $shell, not nologin"
grep -q "^markerd:x:$gid:" "$sys/etc/group" || fail "no group markerd with markerd's GID $gid"
grep -q '^gpio:x:' "$sys/etc/group" || fail "no group gpio after systemd-sysusers"
[[ $uid -lt 1000 ]] || fail "markerd's UID $uid is not a system UID"
sys2=$work/sysroot-gpio
mkdir -p "$sys2/etc"
echo 'gpio:x:997:' >"$sys2/etc/group"
systemd-sysusers --root="$sys2" "$sysusers" || fail "systemd-sysusers rejects $sysusers on a root with group gpio"
[[ $(grep -c '^gpio:' "$sys2/etc/group") -eq 1 ]] && grep -q '^gpio:x:997:' "$sys2/etc/group" ||
  fail "systemd-sysusers changed the existing group gpio: $(grep '^gpio:' "$sys2/etc/group" | tr '\n' ' ')"
echo "check-install: sysusers.d: user markerd ($uid:$gid, $home, $shell), group gpio; an existing gpio kept"

# The tmpfiles.d file, applied by systemd-tmpfiles: the device lock directory.
tmpfiles=$work/stage_usr/usr/lib/tmpfiles.d/markerd.conf
if [[ $(id -u) -ne 0 ]]; then
  # Only root may give the directory to root: apply the rest, owners aside.
  echo "check-install: note: not root, so systemd-tmpfiles applies $tmpfiles without its owners"
  awk '!/^[[:space:]]*(#|$)/ && NF >= 5 { $4 = "-"; $5 = "-" } { print }' "$tmpfiles" >"$work/tmpfiles.conf"
  tmpfiles=$work/tmpfiles.conf
fi
systemd-tmpfiles --root="$sys" --create "$tmpfiles" || fail "systemd-tmpfiles --create rejects $tmpfiles"
mode=$(stat -c %a "$sys/run/lock/markerd" 2>/dev/null) || fail "systemd-tmpfiles did not create /run/lock/markerd"
[[ $mode == 1777 ]] || fail "/run/lock/markerd has mode $mode, not 1777"
echo "check-install: tmpfiles.d: /run/lock/markerd mode $mode"
