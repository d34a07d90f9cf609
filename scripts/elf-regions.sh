#!/usr/bin/env bash
# Flash and RAM of a firmware ELF per memory region, from its section headers (binutils'
# readelf, on every Debian machine with gcc; installed through apt when missing).
# Usage: elf-regions.sh ELF NAME:ORIGIN:LENGTH...   (ORIGIN in hex, LENGTH in bytes)
# A loaded section in RAM (.data) also counts in the first region, its load image (flash).
set -euo pipefail
elf="$1"; shift
if ! command -v readelf >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq binutils >/dev/null
fi
declare -a names origins lengths used
for r in "$@"; do
    IFS=: read -r n o l <<<"$r"
    names+=("$n"); origins+=($((16#${o#0x}))); lengths+=("$l"); used+=(0)
done
detail=""
while read -r name type addr size flags; do
    [[ "$flags" == *A* ]] || continue
    a=$((16#$addr)); s=$((16#$size))
    [ "$s" -gt 0 ] || continue
    for i in "${!names[@]}"; do
        if [ "$a" -ge "${origins[$i]}" ] && [ "$a" -lt $((origins[i] + lengths[i])) ]; then
            used[i]=$((used[i] + s))
            detail+="  ${names[$i]} $name $s"$'\n'
            # Initialised RAM is copied from flash at boot: count its image there too.
            if [ "$i" -ne 0 ] && [ "$type" = PROGBITS ]; then
                used[0]=$((used[0] + s))
                detail+="  ${names[0]} $name(load image) $s"$'\n'
            fi
        fi
    done
done < <(readelf -SW "$elf" | sed -n 's/^ *\[ *[0-9]*\] *//p' | awk '{print $1, $2, $3, $5, $7}')
printf '%s' "$detail"
for i in "${!names[@]}"; do
    printf '%-8s %8d of %8d bytes (%3d%%)\n' "${names[$i]}" "${used[$i]}" "${lengths[$i]}" \
        $((100 * used[i] / lengths[i]))
done
