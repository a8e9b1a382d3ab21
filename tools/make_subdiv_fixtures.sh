#!/bin/sh
# Regenerates tests/fixtures/subdiv/opensubdiv_limits.txt: OpenSubdiv's limit points for the
# cages in tools/subdiv_oracle.cpp (creases, corners, boundary rules), which the unit tests in
# src/render/subdiv.rs compare against. Needs a C++ compiler and OpenSubdiv
# (`apt-get install libosd-dev`); the tests themselves need neither.
set -eu
cd "$(dirname "$0")/.."
out=$(mktemp -d)
g++ -O1 -std=c++14 -o "$out/subdiv_oracle" tools/subdiv_oracle.cpp -losdCPU
mkdir -p tests/fixtures/subdiv
"$out/subdiv_oracle" > tests/fixtures/subdiv/opensubdiv_limits.txt
rm -r "$out"
