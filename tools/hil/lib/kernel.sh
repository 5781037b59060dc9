# shellcheck shell=bash
# Debian's kernel for the HIL guest, sourced by tools/hil/hil-run.
#
# The kernel is never installed: its packages are downloaded with apt-get and
# unpacked with dpkg-deb into a cache directory keyed on the kernel ABI and
# package version, together with the out-of-tree modules built against it
# (tools/hil/modules/<name>/) and each module's dependencies.
#
# Cache layout, under $HIL_CACHE (default ~/.cache/markerd-hil):
#   <kver>_<version>/root/          the unpacked image, headers and kbuild packages
#   <kver>_<version>/vmlinux        the kernel uncompressed, when it boots as PVH
#   <kver>_<version>/modules.index  "<name> <path>" for every module of the image
#   <kver>_<version>/depends/<name> the module's modinfo depends=, one name a line
#   <kver>_<version>/src/           the few linux-source files the recipes need
#   <kver>_<version>/oot/<name>-<recipe hash>/<name>.ko
#   <kver>_<version>.prepare.lock   held exclusively while anything is added
#   <kver>_<version>.use.lock       held shared by every run using the entry
#   apt-lookup                      apt's current kernel, until its lists change
# An entry becomes visible by one rename when it is complete, and old entries
# are removed only when no run holds them, so concurrent runs are safe.
#
# Errors: hil_fail (exit 125) for what is broken, hil_skip (exit 77) for what
# this machine cannot do (no network and no cache).

hil_kernel_flavour=amd64

# Sets HIL_KVER (6.1.0-57-amd64), HIL_KVERSION (6.1.192-3) and HIL_KSERIES (6.1)
# from apt's view of linux-image-<flavour>; empty when apt knows nothing. The
# answer is kept until apt's package lists change: without a pkgcache.bin (as
# in Debian's container images) each apt-cache call parses them all, seconds.
hil_kernel_lookup() {
  HIL_KVER='' HIL_KVERSION='' HIL_KSERIES=''
  local memo=$HIL_CACHE/apt-lookup lists=/var/lib/apt/lists
  if [[ -s $memo && -z $(find "$lists" -maxdepth 1 -newer "$memo" -print -quit 2>/dev/null) ]]; then
    read -r HIL_KVER HIL_KVERSION <"$memo"
  else
    local image
    image=$(apt-cache depends "linux-image-$hil_kernel_flavour" 2>/dev/null |
      awk '$1 == "Depends:" && $2 ~ /^linux-image-[0-9]/ { print $2; exit }') || true
    [[ -n $image ]] || return 0
    HIL_KVERSION=$(apt-cache policy "$image" 2>/dev/null | awk '$1 == "Candidate:" { print $2; exit }') || true
    [[ -n $HIL_KVERSION && $HIL_KVERSION != "(none)" ]] || { HIL_KVERSION=; return 0; }
    HIL_KVER=${image#linux-image-}
    local tmp
    tmp=$(mktemp "$memo.XXXXXX")
    printf '%s %s\n' "$HIL_KVER" "$HIL_KVERSION" >"$tmp"
    mv -f "$tmp" "$memo"
  fi
  HIL_KSERIES=$(cut -d. -f1,2 <<<"$HIL_KVERSION")
}

hil_apt_download() {  # <dir> <package=version>...
  local dir=$1; shift
  local sandbox=()
  # _apt cannot write into a private temp directory; downloading as root there
  # is what apt would fall back to anyway, without the warning.
  [[ $(id -u) -eq 0 ]] && sandbox=(-o APT::Sandbox::User=root)
  (cd "$dir" && apt-get download -q=2 "${sandbox[@]}" "$@")
}

# Chooses the cache entry to use and makes sure it is complete: HIL_KDIR,
# HIL_KVER, HIL_KVERSION, HIL_KSERIES, HIL_HEADERS (the kbuild directory).
hil_kernel_prepare() {
  mkdir -p "$HIL_CACHE"
  hil_kernel_lookup
  local key=
  [[ -n $HIL_KVER ]] && key=${HIL_KVER}_${HIL_KVERSION}
  if [[ -z $key || ! -e $HIL_CACHE/$key/complete ]]; then
    if [[ -z $key ]]; then
      hil_log "apt knows no linux-image-$hil_kernel_flavour (run apt-get update)"
    elif ! hil_kernel_populate "$key"; then
      hil_log "could not download Debian's kernel $HIL_KVER $HIL_KVERSION"
      key=
    fi
    if [[ -z $key ]]; then
      # Offline, an older Debian kernel from the cache still meets the real
      # drivers; it is only not the newest one.
      key=$(hil_kernel_newest_cached)
      [[ -n $key ]] || hil_skip "no network to download Debian's kernel and nothing in the cache $HIL_CACHE"
      hil_log "using the cached kernel $key instead"
      HIL_KVER=${key%%_*}
      HIL_KVERSION=${key#*_}
      HIL_KSERIES=$(cut -d. -f1,2 <<<"$HIL_KVERSION")
    fi
  fi
  HIL_KDIR=$HIL_CACHE/$key
  HIL_HEADERS=$HIL_KDIR/root/usr/src/linux-headers-$HIL_KVER
  # Held (shared) until this process exits, so that no other run prunes it.
  exec {hil_use_lock}>"$HIL_KDIR.use.lock"
  flock -s "$hil_use_lock"
  [[ -e $HIL_KDIR/complete ]] || hil_fail "the cache entry $HIL_KDIR vanished"
  hil_kernel_prune "$key"
}

hil_kernel_newest_cached() {
  local d
  for d in "$HIL_CACHE"/*/complete; do
    if [[ -e $d ]]; then printf '%s %s\n' "$(stat -c %Y "$d")" "$(basename "$(dirname "$d")")"; fi
  done | sort -n | tail -n 1 | cut -d' ' -f2
}

# Downloads and unpacks one kernel into the cache (under its prepare lock);
# returns non-zero only when the download fails.
hil_kernel_populate() {
  local key=$1 lock
  exec {lock}>"$HIL_CACHE/$key.prepare.lock"
  flock -x "$lock"
  if [[ -e $HIL_CACHE/$key/complete ]]; then
    exec {lock}>&-
    return 0
  fi
  local started=$SECONDS tmp
  tmp=$(mktemp -d "$HIL_CACHE/.$key.XXXXXX")
  mkdir "$tmp/debs" "$tmp/root" "$tmp/depends" "$tmp/src" "$tmp/oot"
  local common=linux-headers-${HIL_KVER%-"$hil_kernel_flavour"}-common
  hil_log "downloading Debian's kernel $HIL_KVER ($HIL_KVERSION)"
  if ! hil_apt_download "$tmp/debs" "linux-image-$HIL_KVER=$HIL_KVERSION" \
      "linux-headers-$HIL_KVER=$HIL_KVERSION" "$common=$HIL_KVERSION" \
      "linux-kbuild-$HIL_KSERIES=$HIL_KVERSION"; then
    rm -rf "$tmp"
    exec {lock}>&-
    return 1
  fi
  local deb
  for deb in "$tmp"/debs/*.deb; do
    dpkg-deb -x "$deb" "$tmp/root" || hil_fail "cannot unpack $deb"
  done
  rm -rf "$tmp/debs"

  # The headers' Makefile includes the -common tree by its absolute /usr/src
  # path; make runs it from its own directory, so a relative path finds the
  # unpacked tree wherever the cache is.
  local makefile=$tmp/root/usr/src/linux-headers-$HIL_KVER/Makefile
  grep -q "^include /usr/src/$common/Makefile" "$makefile" ||
    hil_fail "unexpected $makefile: $(head -n 3 "$makefile")"
  sed -i "s|^include /usr/src/$common/Makefile|include ../$common/Makefile|" "$makefile"

  # Modules compressed by later Debian kernels are stored plain: insmod in the
  # initramfs and the modinfo reader then need no decompressor.
  find "$tmp/root/lib/modules" -name '*.ko.xz' -exec xz -d {} + || hil_fail "cannot decompress the modules"
  find "$tmp/root/lib/modules/$HIL_KVER/kernel" -name '*.ko' -printf '%f %P\n' |
    awk '{ name = $1; sub(/\.ko$/, "", name); gsub("-", "_", name); print name, "kernel/" $2 }' \
    >"$tmp/modules.index"
  [[ -s $tmp/modules.index && -e $tmp/root/boot/vmlinuz-$HIL_KVER ]] ||
    hil_fail "the package linux-image-$HIL_KVER holds no kernel or no modules"

  hil_kernel_pvh "$tmp/root/boot/vmlinuz-$HIL_KVER" "$tmp/vmlinux"

  touch "$tmp/complete"
  mv -T "$tmp" "$HIL_CACHE/$key"
  hil_log "kernel $key unpacked into $HIL_CACHE in $((SECONDS - started)) s"
  exec {lock}>&-
}

# Unpacks the kernel from its bzImage when it has a PVH entry point: qemu then
# starts it directly, without the BIOS's real-mode load and the decompressor,
# which take seconds under TCG. Debian's 6.1 kernels are xz-compressed; xz
# stops at the end of its stream (the bzImage has more after it).
hil_kernel_pvh() {  # <bzImage> <vmlinux>
  local offset
  offset=$(grep -abo -m 1 $'\xfd7zXZ\x00' "$1" | head -n 1 | cut -d: -f1) || true
  if [[ -z $offset ]] || ! xz -dc --single-stream <(tail -c "+$((offset + 1))" "$1") >"$2" 2>/dev/null ||
      ! readelf -n "$2" 2>/dev/null | grep -q 'Xen.*0x00000012'; then
    rm -f "$2"
    hil_log "no PVH kernel in $1: booting it through the BIOS (slower)"
  fi
}

# Removes other cache entries that no run is using (a cache holds one kernel
# in use), and the remains of a download or build that was interrupted.
hil_kernel_prune() {
  local keep=$1 path key prepare use
  for path in "$HIL_CACHE"/*/complete "$HIL_CACHE"/.*.??????; do
    [[ -e $path ]] || continue
    if [[ $path == */complete ]]; then
      path=$(dirname "$path")
      key=$(basename "$path")
      [[ $key == "$keep" ]] && continue
    else
      key=$(basename "$path")
      key=${key#.}
      key=${key%.*}
    fi
    exec {prepare}>"$HIL_CACHE/$key.prepare.lock"
    if flock -n -x "$prepare"; then
      exec {use}>"$HIL_CACHE/$key.use.lock"
      # A half-written entry is in use only while its prepare lock is held.
      if [[ $path == */.* ]] || flock -n -x "$use"; then
        hil_log "removing the unused cache entry $path"
        rm -rf "$path"
      fi
      exec {use}>&-
    fi
    exec {prepare}>&-
  done
}

# Sets REPLY to the module file for a module name (dashes and underscores
# alike): an out-of-tree recipe in tools/hil/modules/<name>/ replaces the
# kernel's own module of that name, and is built when the cache lacks it.
hil_module_path() {
  local name=${1//-/_} recipe
  for recipe in "$HIL_TOOLS/modules"/*/; do
    recipe=${recipe%/}
    if [[ $(basename "$recipe" | tr - _) == "$name" ]]; then
      hil_oot_module "$recipe"
      return
    fi
  done
  local rel
  rel=$(awk -v n="$name" '$1 == n { print $2; exit }' "$HIL_KDIR/modules.index")
  [[ -n $rel ]] || hil_fail "Debian's kernel $HIL_KVER has no module '$1' (and tools/hil/modules/ no recipe for it)"
  REPLY=$HIL_KDIR/root/lib/modules/$HIL_KVER/$rel
}

# Sets HIL_DEPENDS to the names a module file depends on (its modinfo
# depends= field), memoised in the cache.
hil_module_depends() {  # <name> <path>
  local memo=$HIL_KDIR/depends/$1
  if [[ ! -e $memo || $memo -ot $2 ]]; then
    local section tmp
    section=$(mktemp)
    objcopy -O binary --only-section=.modinfo "$2" "$section" || hil_fail "cannot read the modinfo of $2"
    tmp=$(mktemp "$memo.XXXXXX")
    tr '\0' '\n' <"$section" | sed -n 's/^depends=//p' | tr ',' '\n' | sed '/^$/d; s/-/_/g' >"$tmp"
    mv -f "$tmp" "$memo"
    rm -f "$section"
  fi
  mapfile -t HIL_DEPENDS <"$memo"
}

# Sets HIL_MODULE_ORDER to the files of the named modules and of everything
# they depend on, each after its dependencies and each once.
hil_module_order() {
  HIL_MODULE_ORDER=()
  declare -gA hil_module_seen=()
  local m
  for m in "$@"; do hil_module_visit "$m"; done
}

hil_module_visit() {
  local name=${1//-/_} path dep
  [[ -n ${hil_module_seen[$name]:-} ]] && return
  hil_module_seen[$name]=1
  hil_module_path "$name"
  path=$REPLY
  hil_module_depends "$name" "$path"
  local -a depends=("${HIL_DEPENDS[@]}")
  for dep in "${depends[@]}"; do hil_module_visit "$dep"; done
  HIL_MODULE_ORDER+=("$path")
}

# Builds an out-of-tree module from its recipe directory once per kernel and
# recipe content; sets REPLY to the .ko. A recipe holds `sources` (paths in
# linux-source, copied flat into the build directory), `Kbuild`, and
# optionally `prepare.sh`, run in the build directory with HIL_RECIPE set to
# the recipe (for patches kept beside it).
hil_oot_module() {
  local recipe=$1 name hash out
  name=$(basename "$recipe")
  hash=$(cd "$recipe" && find . -type f -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -c1-16)
  out=$HIL_KDIR/oot/$name-$hash
  if [[ ! -e $out/$name.ko ]]; then
    local lock
    exec {lock}>"$HIL_KDIR.prepare.lock"
    flock -x "$lock"
    [[ -e $out/$name.ko ]] || hil_oot_build "$recipe" "$name" "$out"
    exec {lock}>&-
  fi
  REPLY=$out/$name.ko
}

hil_oot_build() {  # <recipe> <name> <out>
  local recipe=$1 name=$2 out=$3 started=$SECONDS
  local -a files
  mapfile -t files < <(sed 's/#.*//; /^[[:space:]]*$/d' "$recipe/sources")
  hil_kernel_sources "${files[@]}"
  local build f
  rm -rf "$HIL_KDIR/oot/.$name".*  # failed builds, kept until now for their logs
  build=$(mktemp -d "$HIL_KDIR/oot/.$name.XXXXXX")
  for f in "${files[@]}"; do cp "$HIL_KDIR/src/$f" "$build/"; done
  cp "$recipe/Kbuild" "$build/"
  if [[ -e $recipe/prepare.sh ]]; then
    (cd "$build" && HIL_RECIPE=$recipe bash "$recipe/prepare.sh") >"$build/build.log" 2>&1 ||
      hil_fail "$recipe/prepare.sh failed against $HIL_KVER: $(tail -n 5 "$build/build.log")"
  fi
  hil_log "building $name against $HIL_KVER"
  make -C "$HIL_HEADERS" M="$build" -j2 modules >>"$build/build.log" 2>&1 ||
    hil_fail "building $name failed against $HIL_KVER; log: $build/build.log
$(tail -n 20 "$build/build.log")"
  [[ -e $build/$name.ko ]] || hil_fail "building $name made no $name.ko (see $build/build.log)"
  rm -rf "$out"
  mv -T "$build" "$out"
  # Builds of earlier versions of the recipe are not used again.
  find "$HIL_KDIR/oot" -mindepth 1 -maxdepth 1 -name "$name-*" ! -path "$out" -exec rm -rf {} +
  hil_log "built $name in $((SECONDS - started)) s"
}

# Makes sure the given linux-source paths are in the cache's src/; downloads
# linux-source (large) only when one is missing. Called under the prepare lock.
hil_kernel_sources() {
  local -a missing=()
  local f
  for f in "$@"; do [[ -e $HIL_KDIR/src/$f ]] || missing+=("linux-source-$HIL_KSERIES/$f"); done
  [[ ${#missing[@]} -gt 0 ]] || return 0
  # While the package is here, every recipe's files are taken, so that the
  # first build of another recipe does not fetch it again.
  local -A wanted=()
  for f in "${missing[@]}"; do wanted[$f]=1; done
  while read -r f; do
    [[ -e $HIL_KDIR/src/$f || -n ${wanted[linux-source-$HIL_KSERIES/$f]:-} ]] && continue
    wanted[linux-source-$HIL_KSERIES/$f]=1
    missing+=("linux-source-$HIL_KSERIES/$f")
  done < <(cat "$HIL_TOOLS"/modules/*/sources | sed 's/#.*//; /^[[:space:]]*$/d')
  rm -rf "$HIL_KDIR"/.src.*  # an interrupted download's 140 MB
  local tmp
  tmp=$(mktemp -d "$HIL_KDIR/.src.XXXXXX")
  hil_log "downloading linux-source-$HIL_KSERIES $HIL_KVERSION for ${missing[*]#linux-source-"$HIL_KSERIES"/}"
  hil_apt_download "$tmp" "linux-source-$HIL_KSERIES=$HIL_KVERSION" ||
    { rm -rf "$tmp"; hil_skip "cannot download linux-source-$HIL_KSERIES $HIL_KVERSION to build the out-of-tree modules"; }
  dpkg-deb --fsys-tarfile "$tmp"/linux-source-*.deb |
    tar -xO "./usr/src/linux-source-$HIL_KSERIES.tar.xz" |
    tar -xJ -C "$tmp" "${missing[@]}" ||
    { rm -rf "$tmp"; hil_fail "linux-source-$HIL_KSERIES $HIL_KVERSION lacks one of: ${missing[*]}"; }
  for f in "${missing[@]}"; do
    mkdir -p "$(dirname "$HIL_KDIR/src/${f#*/}")"
    mv "$tmp/$f" "$HIL_KDIR/src/${f#*/}"
  done
  rm -rf "$tmp"
}
