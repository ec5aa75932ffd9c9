#!/usr/bin/env bash
# Builds the rig boards' firmware with Debian's AVR toolchain (gcc-avr, avr-libc, binutils-avr)
# and checks each image against its board:
#
#   rig_drivers/scripts/build_firmware.sh <outdir> [<objdir>]   (objects: <outdir>/obj by default)
#
# Images (ELF and Intel HEX in <outdir>):
#   track_drv_mega2560       TrackDRV, Arduino Mega 2560 (ATmega2560)
#   car_drv_mega2560         CarDRV,   Arduino Mega 2560 (ATmega2560)
#   truck_drv_leonardo       TruckDRV, Arduino Leonardo (ATmega32u4), link on pins 0/1
#   *_mega2560_emu           the three boards' logic for qemu-system-avr's Mega 2560, inputs from
#                            the adapters' stubs (RIG_EMULATED_INPUTS, see src/firmware/avr/)
#
# Each image's flash (.text + .data) must fit the board's flash less its bootloader, and its
# static RAM (.data + .bss) may use at most 75 % of the board's RAM, leaving the rest to the stack.
# <outdir>/sizes.txt gets the table; the script fails naming any image over a limit.
# Sources: the board logic (src/protocol/codec.cpp, src/firmware/{firmware,*_drv}.cpp), the same
# files the host build compiles, and the AVR adapters in src/firmware/avr/.
set -euo pipefail

OUT=${1:?usage: build_firmware.sh <outdir> [<objdir>]}
OBJ=${2:-$OUT/obj}
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"  # rig_drivers/
mkdir -p "$OUT" "$OBJ"
OUT="$(cd "$OUT" && pwd)"

CXX=${AVR_CXX:-avr-g++}
for tool in "$CXX" avr-objcopy avr-size; do
  command -v "$tool" >/dev/null ||
    { echo "build_firmware.sh: $tool not found: install gcc-avr avr-libc binutils-avr" >&2; exit 1; }
done
LAUNCHER=()
command -v ccache >/dev/null && LAUNCHER=(ccache)

# C++14 is what gcc-avr 5.4 has; no exceptions, no RTTI, no heap; unused code is dropped at link.
CXXFLAGS=(-std=gnu++14 -Os -DF_CPU=16000000UL -Wall -Wextra -Werror -fno-exceptions -fno-rtti
          -fno-threadsafe-statics -ffunction-sections -fdata-sections -I"$HERE/include")
LOGIC=(protocol/codec.cpp firmware/firmware.cpp)

# build <image> <mcu> <board source> <logic source> <emulated 0|1>
build() {
  local image=$1 mcu=$2 board=$3 logic=$4 emu=$5 objs=() s o
  for s in "${LOGIC[@]}" "firmware/$logic" firmware/avr/avr_io.cpp firmware/avr/avr_main.cpp \
           "firmware/avr/$board"; do
    o="$OBJ/$mcu-$emu-$(basename "$s" .cpp).o"
    "${LAUNCHER[@]}" "$CXX" -mmcu="$mcu" "${CXXFLAGS[@]}" -DRIG_EMULATED_INPUTS="$emu" \
      -c "$HERE/src/$s" -o "$o"
    objs+=("$o")
  done
  "$CXX" -mmcu="$mcu" -Wl,--gc-sections "${objs[@]}" -o "$OUT/$image.elf"
  avr-objcopy -O ihex -R .eeprom "$OUT/$image.elf" "$OUT/$image.hex"
}

build track_drv_mega2560 atmega2560 track_board.cpp track_drv.cpp 0
build car_drv_mega2560 atmega2560 car_board.cpp car_drv.cpp 0
build truck_drv_leonardo atmega32u4 truck_board.cpp truck_drv.cpp 0
build track_drv_mega2560_emu atmega2560 track_board.cpp track_drv.cpp 1
build car_drv_mega2560_emu atmega2560 car_board.cpp car_drv.cpp 1
build truck_drv_mega2560_emu atmega2560 truck_board.cpp truck_drv.cpp 1

# Board limits: flash less the bootloader (Mega 2560: 8 KB stk500v2; Leonardo: 4 KB Caterina),
# static RAM at most 75 % of the SRAM.
limits() {
  case $1 in
    atmega2560) echo "$((256 * 1024 - 8 * 1024)) 8192" ;;
    atmega32u4) echo "$((32 * 1024 - 4 * 1024)) 2560" ;;
  esac
}
section() { avr-size -A "$1" | awk -v s="$2" '$1 == s { print $2; found = 1 } END { if (!found) print 0 }'; }

fail=0
rm -f "$OUT/sizes.txt"  # written only when every image fits (a build target's output)
{
  printf '%-24s %-11s %8s %8s %6s %6s %6s %6s\n' image mcu flash_B limit_B flash% ram_B sram_B ram%
  for elf in "$OUT"/*.elf; do
    image=$(basename "$elf" .elf)
    mcu=$(case $image in *leonardo*) echo atmega32u4 ;; *) echo atmega2560 ;; esac)
    read -r flash_limit sram < <(limits "$mcu")
    text=$(section "$elf" .text)
    data=$(section "$elf" .data)
    bss=$(section "$elf" .bss)
    noinit=$(section "$elf" .noinit)
    flash=$((text + data))
    ram=$((data + bss + noinit))
    printf '%-24s %-11s %8d %8d %6s %6d %6d %6s\n' "$image" "$mcu" "$flash" "$flash_limit" \
      "$(awk -v a="$flash" -v b="$flash_limit" 'BEGIN { printf "%.1f", 100 * a / b }')" \
      "$ram" "$sram" "$(awk -v a="$ram" -v b="$sram" 'BEGIN { printf "%.1f", 100 * a / b }')"
    if [ "$flash" -gt "$flash_limit" ]; then
      echo "build_firmware.sh: $image: flash $flash B exceeds $flash_limit B" >&2
      fail=1
    fi
    if [ $((ram * 4)) -gt $((sram * 3)) ]; then
      echo "build_firmware.sh: $image: static RAM $ram B exceeds 75 % of $sram B" >&2
      fail=1
    fi
  done
} >"$OUT/sizes.txt.tmp"
cat "$OUT/sizes.txt.tmp"
[ "$fail" = 0 ] && mv "$OUT/sizes.txt.tmp" "$OUT/sizes.txt"
exit $fail
