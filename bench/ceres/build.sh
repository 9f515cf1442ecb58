#!/usr/bin/env bash
# Build the Ceres peer for problems of N1, N2, … free arm parameters (one ceres::Jet size each;
# a size takes seconds to compile, so only the sizes asked for are built) into OUT_DIR, unless a
# binary newer than every source is there already; print the binary's path.
#
#   bench/ceres/build.sh OUT_DIR N1 [N2 …]
#
# Needs g++, libceres-dev and nlohmann-json3-dev (scripts/setup.sh installs them). Flags as
# CMake's Release build, -O3 -DNDEBUG; no -march=native (kincal's release build has none).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if [ $# -lt 2 ]; then
    echo "usage: bench/ceres/build.sh OUT_DIR N1 [N2 ...]  (N: free arm parameters, 1..60)" >&2
    exit 2
fi
mkdir -p "$1"
out="$(cd "$1" && pwd)"
shift
sizes=($(printf '%s\n' "$@" | sort -n -u))
for n in "${sizes[@]}"; do
    if ! [[ "$n" =~ ^[0-9]+$ ]] || [ "$n" -lt 1 ] || [ "$n" -gt 60 ]; then
        echo "bench/ceres/build.sh: size \"$n\": expected a count of free parameters, 1..60" >&2
        exit 2
    fi
done
for header in ceres/ceres.h nlohmann/json.hpp eigen3/Eigen/Dense; do
    if [ ! -f "/usr/include/$header" ]; then
        echo "bench/ceres/build.sh: /usr/include/$header is missing: run scripts/setup.sh" \
            "(it installs libceres-dev and nlohmann-json3-dev)" >&2
        exit 1
    fi
done
tag="$(IFS=_; echo "${sizes[*]}")"
bin="$out/ceres_peer_n$tag"
flags=(-std=c++17 -O3 -DNDEBUG -Wall -Wextra -I/usr/include/eigen3)
# Rebuild an object when its source, a header or this script is newer.
build() { # object source [flags]
    local obj="$1" src="$2" stale=0
    shift 2
    [ -f "$obj" ] || stale=1
    for dep in "$src" "$here"/*.h "$here/build.sh"; do [ "$dep" -nt "$obj" ] && stale=1; done
    if [ "$stale" = 1 ]; then g++ "${flags[@]}" "$@" -c "$src" -o "$obj.tmp.$$" && mv "$obj.tmp.$$" "$obj"; fi
}
pids=()
for name in read solve main; do
    build "$out/$name.o" "$here/$name.cc" &
    pids+=($!)
done
build "$out/chain_n$tag.o" "$here/chain.cc" "-DKINCAL_PEER_SIZES=$(IFS=,; echo "${sizes[*]}")" &
pids+=($!)
for pid in "${pids[@]}"; do wait "$pid"; done
objects=("$out/read.o" "$out/solve.o" "$out/main.o" "$out/chain_n$tag.o")
stale=0
[ -x "$bin" ] || stale=1
for obj in "${objects[@]}"; do [ "$obj" -nt "$bin" ] && stale=1; done
if [ "$stale" = 1 ]; then
    g++ "${objects[@]}" -o "$bin.tmp.$$" -lceres -lglog -lgflags -lpthread
    mv "$bin.tmp.$$" "$bin"
fi
echo "$bin"
