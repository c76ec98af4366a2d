//! A large proxy scene with real statistics: a scene tiled side by side on a grid (the RD
//! search's speed at scale, docs/codec.md "Encode speed at scale").
//!
//! `cargo run --release --example tile_scene -- IN.ply OUT.ply [NX] [NZ]`
//!
//! Copies of IN (default 2 × 2) are laid out along x and z (the orbit's up axis is −y), each
//! shifted by the scene's extent along that axis, so e.g. playbot-lod3 (31,000 Gaussians) gives a
//! 124,000-Gaussian scene whose attributes have the input's distributions.

#[path = "../benches/common/proxy.rs"]
mod proxy;

use gscodec::io::ply::{read_ply, write_ply};
use std::path::Path;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: tile_scene IN.ply OUT.ply [NX] [NZ]");
        std::process::exit(2);
    }
    let count = |i: usize| args.get(i).map_or(2, |v| v.parse::<usize>().expect("a tile count"));
    let (nx, nz) = (count(3), count(4));
    let scene = read_ply(Path::new(&args[1])).expect("read the input");
    let out = proxy::tiled(&scene, nx, nz);
    write_ply(Path::new(&args[2]), &out).expect("write the output");
    eprintln!("{}: {} Gaussians ({nx} × {nz} copies of {})", args[2], out.len(), args[1]);
}
