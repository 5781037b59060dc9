# bash completion for markerctl (installed as
# <prefix>/share/bash-completion/completions/markerctl, where
# bash-completion loads it on the first `markerctl <TAB>`; or source it).
# Completes the commands, nested ones too (rig move, sweep start), each
# command's options, the values of options that take a fixed set of words,
# and files, directories or devices where a command takes them ("-", standard
# input, too where a command reads a file: after a typed "-").
#
# The words are written out here rather than asked of markerctl at each
# TAB: no program runs while typing. tests/completion/check-completion.sh
# compares them with what `markerctl CMD --help` lists, so a command or an
# option added without its completion fails the tests.

# The command path (the words that name the command, "rig move") and the
# options of each: a "=" after an option means it takes a value.
_markerctl_spec() {  # PATH -> "subcommands|options"
  local socket="--socket="
  case $1 in
    "")
      echo "marker render detect evaluate rig cameras camera status detections call snapshot sweep report" \
        "calibrate|-h --help --version"
      ;;
    marker)
      echo "|--family= --id= --size= --margin= --dpi= --image-px= --no-quiet-zone --json -o= --output= -h -h" \
        "--help --board= --board-type= --marker-size= --spacing= --dictionary= --first-id="
      ;;
    render)
      echo "|--dist= --yaw= --pitch= --roll= --offset-x= --offset-y= --family= --id= --size= --camera= --noise=" \
        "--noise-model= --blur= --blur-model= --exposure= --supersample= --no-clutter --background= --no-distort" \
        "--cut-hole --frame= --frame-reflectance= --insert= --margin= --cover= --cover-depth= --cover-reflectance=" \
        "--cover-height= --background-grey= --ambient= --seed= --json -o= --output= -h --help"
      ;;
    detect)
      echo "|--family= --camera= --size= --decimate= --threshold-offset= --min-margin= --blur-sigma= --mounting=" \
        "--uniform-ids --debug= -v --verbose --json -h --help"
      ;;
    evaluate)
      echo "|--family= --dist= --yaw= --yaw-at= --frames= --noise= --blur= --supersample= --camera= --size= --seed=" \
        "--json -q --quiet -h --help"
      ;;
    # rig's own options may also follow its command (CLI11's fallthrough).
    rig) echo "status home move jog stop|--config= $socket -h -h --help" ;;
    "rig status") echo "|--json --config= $socket -h -h --help" ;;
    "rig home") echo "|--axis= --no-wait --json --config= $socket -h -h --help" ;;
    "rig move" | "rig jog") echo "|--rail= --turntable= --home --no-wait --json --config= $socket -h -h --help" ;;
    "rig stop") echo "|--emergency --no-wait --json --config= $socket -h -h --help" ;;
    cameras) echo "|--backend= --json -h -h --help" ;;
    camera) echo "get set|-h --help" ;;
    "camera get" | "camera set") echo "|$socket --json -h -h --help" ;;
    status) echo "|$socket --json -h -h --help" ;;
    detections) echo "|$socket --count= -h -h --help" ;;
    call) echo "|$socket --timeout= -h -h --help" ;;
    snapshot) echo "|-o= --output= --annotate --json $socket -h -h --help" ;;
    sweep) echo "check start status pause resume abort|-h --help" ;;
    "sweep check") echo "|--config= $socket --json -h -h --help" ;;
    "sweep start") echo "|--wait $socket --json -h -h --help" ;;
    "sweep status") echo "|--follow $socket --json -h -h --help" ;;
    "sweep pause" | "sweep resume") echo "|$socket --json -h -h --help" ;;
    "sweep abort") echo "|--reason= $socket --json -h -h --help" ;;
    report) echo "|--paper= --socket= -o= --output= --no-plots --json -h -h --help" ;;
    calibrate)
      echo "|--board= --board-type= --size= --marker-size= --spacing= --dictionary= --first-id= --model= --fix-k3" \
        "--min-views= --min-coverage= -o= --output= --ros= --camera-name= --live= --keep= --socket= --rig= --rig-out=" \
        "--fix= --free= --json" \
        "-h --help"
      ;;
  esac
}

# Files: those matching GLOB (all when empty), and directories to go into.
_markerctl_files() {  # CURRENT [GLOB]
  compopt -o filenames 2>/dev/null
  if [[ -n ${2-} ]]; then
    mapfile -t COMPREPLY < <(compgen -f -X "!$2" -- "$1"; compgen -d -- "$1")
  else
    mapfile -t COMPREPLY < <(compgen -f -- "$1")
  fi
}

_markerctl_directories() {  # CURRENT
  compopt -o filenames 2>/dev/null
  mapfile -t COMPREPLY < <(compgen -d -- "$1")
}

_markerctl_words() {  # CURRENT WORD...
  local current=$1
  shift
  mapfile -t COMPREPLY < <(compgen -W "$*" -- "$current")
}

# The value of OPTION in command PATH.
_markerctl_value() {  # PATH OPTION CURRENT
  local path=$1 option=$2 cur=$3
  case $option in
    --family)
      if [[ $path == evaluate ]]; then
        _markerctl_words "$cur" frame8 aruco4x4_50 tag36h11 all
      else
        _markerctl_words "$cur" frame8 aruco4x4_50 tag36h11
      fi
      ;;
    --camera) _markerctl_files "$cur" "*.y*ml" ;;
    --config) _markerctl_files "$cur" "*.toml" ;;
    --debug | --keep) _markerctl_directories "$cur" ;;
    --paper | --rig) _markerctl_directories "$cur" ;;
    --rig-out) _markerctl_files "$cur" "*.toml" ;;
    --fix | --free)
      _markerctl_words "$cur" fx fy cx cy k1 k2 p1 p2 k3 d0_mm yaw0_deg marker_offset_normal_mm \
        marker_offset_lateral_mm camera_offset_x_mm camera_offset_y_mm rail_tilt_x_deg rail_tilt_y_deg intrinsics \
        distortion geometry
      ;;
    --socket)
      # report's --socket is the socket marker's runs; elsewhere markerd's socket.
      if [[ $path == report ]]; then _markerctl_directories "$cur"; else _markerctl_files "$cur"; fi
      ;;
    -o | --output)
      if [[ $path == report ]]; then _markerctl_directories "$cur"; else _markerctl_files "$cur"; fi
      ;;
    --mounting) _markerctl_words "$cur" paper socket switch cut_hole ;;
    --noise-model) _markerctl_words "$cur" gaussian shot ;;
    --blur-model) _markerctl_words "$cur" gaussian disc ;;
    --background) _markerctl_words "$cur" shapes tiles keyboard checkerboard windows text outlets ;;
    --frame) _markerctl_words "$cur" none socket switch ;;
    --insert) _markerctl_words "$cur" none socket rocker ;;
    --cover) _markerctl_words "$cur" top right bottom left ;;
    --backend) _markerctl_words "$cur" v4l2 libcamera all ;;
    --axis) _markerctl_words "$cur" rail turntable ;;
    --board-type) _markerctl_words "$cur" chessboard charuco frame8 ;;
    # calibrate's --board is also a board file; marker's is COLSxROWS only.
    --board) if [[ $path == calibrate ]]; then _markerctl_files "$cur" "*.toml"; else COMPREPLY=(); fi ;;
    --dictionary)
      _markerctl_words "$cur" 4x4_50 4x4_100 4x4_250 4x4_1000 5x5_50 5x5_100 5x5_250 5x5_1000 6x6_50 6x6_100 \
        6x6_250 6x6_1000 7x7_50 7x7_100 7x7_250 7x7_1000 aruco_original apriltag_16h5 apriltag_25h9 \
        apriltag_36h10 apriltag_36h11
      ;;
    --model) _markerctl_words "$cur" plumb_bob rational_polynomial ;;
    --ros) _markerctl_files "$cur" "*.y*ml" ;;
    *) COMPREPLY=() ;;  # a number, a length, an angle, a text: nothing to offer
  esac
}

# Whether a command reads "-" as standard input where it takes a file (or,
# for call, its arguments).
_markerctl_reads_stdin() {  # PATH
  case $1 in
    detect | "sweep check" | "sweep start" | call) return 0 ;;
    *) return 1 ;;
  esac
}

# What a command takes where no option is being completed.
_markerctl_arguments() {  # PATH CURRENT
  local path=$1 cur=$2
  case $path in
    detect | calibrate) _markerctl_files "$cur" ;;
    "sweep check" | "sweep start") _markerctl_files "$cur" "*.toml" ;;
    report) _markerctl_directories "$cur" ;;
    cameras)
      compopt -o filenames 2>/dev/null
      mapfile -t COMPREPLY < <(compgen -G "${cur:-/dev/video}*" 2>/dev/null)
      ;;
    *) COMPREPLY=() ;;
  esac
}

_markerctl() {
  local cur=${COMP_WORDS[COMP_CWORD]}
  local path="" spec subcommands options word i value_of=""
  COMPREPLY=()
  # Walk the words before the cursor: a word that names a subcommand of the
  # path so far extends it; an option that takes a value skips that value.
  for ((i = 1; i < COMP_CWORD; i++)); do
    word=${COMP_WORDS[i]}
    if [[ -n $value_of ]]; then
      value_of=""
      continue
    fi
    spec=$(_markerctl_spec "$path")
    subcommands=" ${spec%%|*} "
    options=" ${spec#*|} "
    if [[ $word == -* ]]; then
      [[ $word != *=* && $options == *" $word= "* ]] && value_of=$word
    elif [[ $subcommands == *" $word "* ]]; then
      path="${path:+$path }$word"
    fi
  done

  if [[ -n $value_of ]]; then
    _markerctl_value "$path" "$value_of" "$cur"
    return 0
  fi
  if [[ $cur == --*=* ]]; then
    # --option=value: the value, after the "=".
    local option=${cur%%=*}
    _markerctl_value "$path" "$option" "${cur#*=}"
    return 0
  fi
  spec=$(_markerctl_spec "$path")
  subcommands=${spec%%|*}
  options=${spec#*|}
  if [[ $cur == -* ]]; then
    _markerctl_words "$cur" "${options//=/}"
    # A lone "-" may be standard input rather than the start of an option.
    if [[ $cur == - ]] && _markerctl_reads_stdin "$path"; then COMPREPLY+=(-); fi
  elif [[ -n $subcommands ]]; then
    _markerctl_words "$cur" "$subcommands"
  else
    _markerctl_arguments "$path" "$cur"
  fi
  return 0
}

complete -F _markerctl markerctl
