#!/usr/bin/env bash
# Builds the npm package in wasm/pkg: the .wasm module (release, LTO), wasm-opt -Oz, then its
# wasm-bindgen glue for `--target web` (ES module + .d.ts); prints the sizes.
#
# Needs: the wasm32-unknown-unknown target (`rustup target add wasm32-unknown-unknown`),
# wasm-bindgen-cli of exactly the wasm-bindgen version in Cargo.lock
# (`cargo install wasm-bindgen-cli --version =X.Y.Z`), and wasm-opt (Debian: `apt-get install binaryen`).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

want=$(awk '/^name = "wasm-bindgen"$/ { getline; gsub(/[^0-9.]/, ""); print; exit }' Cargo.lock)
have=$(wasm-bindgen --version 2>/dev/null | awk '{ print $2 }') || true
if [ "$have" != "$want" ]; then
  echo "error: wasm-bindgen-cli ${have:-missing}, Cargo.lock has wasm-bindgen $want: cargo install wasm-bindgen-cli --version =$want" >&2
  exit 2
fi
command -v wasm-opt >/dev/null || { echo "error: wasm-opt missing: apt-get install binaryen" >&2; exit 2; }

# Size settings for this build only (the workspace's release profile stays as it is).
export CARGO_PROFILE_RELEASE_LTO=true CARGO_PROFILE_RELEASE_CODEGEN_UNITS=1 \
  CARGO_PROFILE_RELEASE_PANIC=abort CARGO_PROFILE_RELEASE_DEBUG=false
cargo build --target wasm32-unknown-unknown --release -p gscodec-wasm
raw="$root/target/wasm32-unknown-unknown/release/gscodec_wasm.wasm"

out="$root/wasm/pkg"
tmp=$(mktemp -d "$root/wasm/.pkg.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
# wasm-opt runs before wasm-bindgen: Debian 12's wasm-opt (binaryen 108) writes the export of
# wasm-bindgen's externref table with the index of the function table, and the module then fails
# to instantiate ("function-typed object must be null"). The flags are the features rustc enables
# by default for wasm32-unknown-unknown.
wasm-opt -Oz --enable-bulk-memory --enable-nontrapping-float-to-int --enable-sign-ext \
  --enable-mutable-globals --enable-multivalue --enable-reference-types \
  "$raw" -o "$tmp/gscodec_wasm.wasm"
wasm-bindgen --target web --out-dir "$tmp" "$tmp/gscodec_wasm.wasm"
rm "$tmp/gscodec_wasm.wasm"
chmod 755 "$tmp"
rm -rf "$out"
mv "$tmp" "$out"
trap - EXIT

wasm_bytes=$(stat -c %s "$out/gscodec_wasm_bg.wasm")
gz_bytes=$(gzip -9 -c "$out/gscodec_wasm_bg.wasm" | wc -c)
js_gz=$(gzip -9 -c "$out/gscodec_wasm.js" | wc -c)
echo "wasm/pkg: gscodec_wasm_bg.wasm $wasm_bytes B ($gz_bytes B gzipped), gscodec_wasm.js $js_gz B gzipped"
