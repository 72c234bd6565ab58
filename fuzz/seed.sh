#!/usr/bin/env bash
# Fill fuzz/corpus/<target>/ with seeds: the small fixtures, the hand-written files in fuzz/seeds/,
# and for `reader` and `reader_sealed` chunk files converted from small fixtures with the release
# binary.
# Run from anywhere; builds the release binary if it is missing. Existing corpus files are kept.
set -euo pipefail

fuzz=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$fuzz")
fixtures=$root/fixtures
corpus=$fuzz/corpus
bin=$root/target/release/strata

mkdir -p "$corpus"/{reader,obj,ply,gltf}

cp "$fixtures"/{cube,icosphere,nonmanifold,open_grid,cad_part}.obj "$corpus/obj/"
cp "$fixtures/colored_sphere.ply" "$fuzz/seeds/quad_ascii.ply" "$fuzz/seeds/tetra_strips_be.ply" "$corpus/ply/"
cp "$fixtures/two_materials.glb" "$fuzz/seeds/tetra_datauri.gltf" "$corpus/gltf/"

if [ ! -x "$bin" ]; then
    (cd "$root" && cargo build --release --quiet)
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
convert() { # <input> <name> [convert flags...]
    local input=$1 name=$2
    shift 2
    "$bin" convert "$input" "$tmp/$name.strata" --quiet "$@" > /dev/null
    cp "$tmp/$name.strata" "$corpus/reader/$name.strata"
}
# Tiny groups so that even a cube gives several levels, nodes, clusters and neighbours in a few
# kB (larger seeds slow every execution down).
tiny=(--cluster-faces 2 --leaf-faces 4 --growth 2 --top-groups 1 --top-faces 2)
convert "$fixtures/cube.obj" cube
convert "$fixtures/cube.obj" cube_levels "${tiny[@]}"
convert "$fixtures/nonmanifold.obj" nonmanifold --normals none
convert "$fixtures/two_materials.glb" two_materials "${tiny[@]}"
convert "$fuzz/seeds/quad_ascii.ply" quad_colors_uvs
convert "$fuzz/seeds/tetra_datauri.gltf" tetra_all_attributes "${tiny[@]}"
# Images (format 2.2): the textured golden vector.
cp "$root/format-spec/vectors/textured.strata" "$corpus/reader/"

mkdir -p "$corpus/reader_sealed"
cp "$corpus"/reader/*.strata "$corpus/reader_sealed/"

for t in reader reader_sealed obj ply gltf; do
    printf '%-7s %3d files, %7d bytes\n' "$t" "$(ls "$corpus/$t" | wc -l)" "$(cat "$corpus/$t"/* | wc -c)"
done
