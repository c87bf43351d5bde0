# bash completion for voxelastic and voxelastic-probe (installed as
# share/bash-completion/completions/voxelastic and .../voxelastic-probe).
# The subcommands and options are read from the program's own --help, so they never go stale:
#   voxelastic <TAB>            the subcommands
#   voxelastic convert --<TAB>  convert's options (and the global -q, -v)
#   anything else               file names

# the words in the sections of --help headed $2 ("Subcommands:" or "Options:", at any indent:
# option groups have their own "Options:"); options are the words that start with '-'
_voxelastic_help_words() {
  local program=$1 section=$2
  shift 2
  "$program" "$@" --help 2>/dev/null | awk -v section="$section" '
    /^\[/ { inside = 0; next }
    /^ *[A-Za-z]+:$/ { h = $1; inside = (h == section); next }
    inside && /^  +[^ ]/ {
      if (section == "Options:" && $1 !~ /^-/) next
      n = split($1, names, ",")
      for (i = 1; i <= n; i++) { sub(/\{.*/, "", names[i]); print names[i] }
    }'
}

_voxelastic() {
  local cur=${COMP_WORDS[COMP_CWORD]} program=${COMP_WORDS[0]} sub="" i w
  # the subcommand is the first word that does not start with '-' (the global flags take no value)
  for ((i = 1; i < COMP_CWORD; i++)); do
    w=${COMP_WORDS[i]}
    if [[ $w != -* ]]; then sub=$w; break; fi
  done
  if [[ $cur == -* ]]; then
    local words
    if [[ -n $sub ]]; then
      words="$(_voxelastic_help_words "$program" "Options:" "$sub") -q --quiet -v --verbose"
    else
      words=$(_voxelastic_help_words "$program" "Options:")
    fi
    mapfile -t COMPREPLY < <(compgen -W "$words" -- "$cur")
    return 0
  fi
  if [[ -z $sub ]]; then
    local subs
    subs=$(_voxelastic_help_words "$program" "Subcommands:")
    if [[ -n $subs ]]; then
      mapfile -t COMPREPLY < <(compgen -W "$subs" -- "$cur")
      return 0
    fi
  fi
  mapfile -t COMPREPLY < <(compgen -f -- "$cur")
  compopt -o filenames 2>/dev/null
  return 0
}
complete -F _voxelastic voxelastic voxelastic-probe
