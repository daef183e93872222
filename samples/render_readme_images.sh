#!/usr/bin/env bash
# Re-render the README's preview images from the sample recipes (needs the project installed in .venv).
#   bash samples/render_readme_images.sh
set -euo pipefail
cd "$(dirname "$0")/.."
bin=.venv/bin/meshdeform
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p docs/images
render() {  # recipe mesh frame [preview options]
    local name=$1 mesh=$2 frame=$3
    shift 3
    "$bin" simulate "samples/meshes/$mesh" -r "samples/recipes/$name.toml" -o "$work/$name" --format obj --quiet
    "$bin" preview "$work/$name" --frames "$frame" --size 480x360 --out "$work/$name-preview" "$@" >/dev/null
    cp "$work/$name-preview/preview/$(printf "%04d" "$frame").png" "docs/images/$name.png"
}
render flag flag.obj 60
render curtain curtain.obj 72
render drop sheet.obj 48
render stressball icosphere.ply 12
render blackhole sheet.obj 100
render rope rope.obj 30
render tear curtain.obj 72
render fold sheet.obj 72 --color displacement  # the flap has travelled farther than the cloth under it
render cape cape.obj 48 --view side  # the body walks to the left, the cape trails behind it
ls -la docs/images
