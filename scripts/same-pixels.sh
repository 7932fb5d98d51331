#!/usr/bin/env bash
# Renders every example and bench scene with `tessera-render` at two revisions and checks that
# each pair of PNGs is byte-identical: a change that claims not to touch a pixel must pass.
#
#   scripts/same-pixels.sh BEFORE [AFTER]
#
# BEFORE and AFTER are git revisions (AFTER defaults to the working tree). The scenes are the
# union of examples/*.ray and bench/scenes*/*.ray at both revisions; a scene that exists at one
# revision only is reported and skipped. Each scene renders with its own sampler and once more
# with each sampler the format has (`--sampler` overrides), so that every sampling path is
# compared, not just the one a scene names. Images are kept under $OUT (default a temporary
# folder) for inspection.
#
# Both revisions build into one target folder (`$CARGO_TARGET_DIR`, default `target/`), one
# after the other: the second build recompiles only the workspace's own crates.
set -euo pipefail

if [ $# -lt 1 ] || [ $# -gt 2 ]; then
  echo "usage: $0 BEFORE [AFTER]" >&2
  exit 2
fi
before=$1
after=${2:-}

top=$(git rev-parse --show-toplevel)
cd "$top"
target=${CARGO_TARGET_DIR:-$top/target}
out=${OUT:-$(mktemp -d)}
work=$(mktemp -d)
trap 'git worktree remove --force "$work/before" >/dev/null 2>&1 || true
      git worktree remove --force "$work/after" >/dev/null 2>&1 || true
      rm -rf "$work"' EXIT

# Builds `tessera-render` from the tree in $1 and copies it to $2. The binary has lived in the
# tracer crate and in a crate of its own (`render/`); either layout builds.
build() {
  local tree=$1 dest=$2
  if [ -f "$tree/render/Cargo.toml" ]; then
    (cd "$tree" && CARGO_TARGET_DIR=$target cargo build --release --quiet -p tessera-render)
  else
    (cd "$tree" && CARGO_TARGET_DIR=$target cargo build --release --quiet -p tessera-tracer \
      --bin tessera-render)
  fi
  cp "$target/release/tessera-render" "$dest"
}

# A checkout of revision $1 in $2, or the working tree itself when $1 is empty.
tree_of() {
  if [ -z "$1" ]; then
    echo "$top"
  else
    git worktree add --quiet --detach "$2" "$1"
    echo "$2"
  fi
}

before_tree=$(tree_of "$before" "$work/before")
after_tree=$(tree_of "$after" "$work/after")
echo "building tessera-render at ${before} and ${after:-the working tree}"
build "$before_tree" "$work/render-before"
build "$after_tree" "$work/render-after"

scenes=$( (cd "$before_tree" && ls examples/*.ray bench/scenes*/*.ray 2>/dev/null
           cd "$after_tree" && ls examples/*.ray bench/scenes*/*.ray 2>/dev/null) | sort -u)

same=0
differ=0
skipped=0
for scene in $scenes; do
  if [ ! -f "$before_tree/$scene" ] || [ ! -f "$after_tree/$scene" ]; then
    echo "skip   $scene (exists at one revision only)"
    skipped=$((skipped + 1))
    continue
  fi
  if ! cmp -s "$before_tree/$scene" "$after_tree/$scene"; then
    echo "skip   $scene (the scene file itself differs)"
    skipped=$((skipped + 1))
    continue
  fi
  for sampler in own center thesis grid jitter adaptive; do
    flags=()
    [ "$sampler" != own ] && flags=(--sampler "$sampler")
    name=$(echo "$scene" | tr '/' '_')
    name=${name%.ray}-$sampler.png
    mkdir -p "$out/before" "$out/after"
    # Rendered from the scene's own folder in each tree, so that its textures resolve there.
    "$work/render-before" "$before_tree/$scene" -o "$out/before/$name" -q "${flags[@]}"
    "$work/render-after" "$after_tree/$scene" -o "$out/after/$name" -q "${flags[@]}"
    if cmp -s "$out/before/$name" "$out/after/$name"; then
      same=$((same + 1))
    else
      echo "DIFFER $scene ($sampler)"
      differ=$((differ + 1))
    fi
  done
done

echo "$same identical, $differ different, $skipped skipped; images in $out"
[ "$differ" -eq 0 ]
