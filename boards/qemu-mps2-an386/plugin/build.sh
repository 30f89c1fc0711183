#!/bin/sh
# Builds insncount.so (next to this script unless OUT is given). Needs only a host C compiler.
set -e
cd "$(dirname "$0")"
cc -shared -fPIC -O2 -Wall -Wextra -fvisibility=hidden -o "${OUT:-$PWD/insncount.so}" insncount.c
