//! Writes the `ros2_bag` fuzz target's seeds into the folder given (scripts/fuzz.sh): a small
//! bag of a transform and a ping (16 beams over 30°, 64 ranges from 1.9 m, uint16) as a whole
//! file with each chunk compression (first byte 0), and as the target's split form (first byte
//! 1, 2, 3: stored, LZ4, zstd).

use std::path::PathBuf;

use epssn_ros2::encode::{self, bag, Compression, Entry};
use epssn_ros2::msgs::{Header, TransformStamped, PROJECTED_SONAR_IMAGE, TF_MESSAGE};

fn main() -> std::io::Result<()> {
    let dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&dir)?;
    let (beams, ranges) = (16usize, 64usize);
    let data = (0..beams * ranges)
        .flat_map(|i| ((i * 977) as u16).to_le_bytes())
        .collect();
    let ranges: Vec<f32> = (0..ranges).map(|i| 1.9 + 0.03 * i as f32).collect();
    let azimuths = encode::even_azimuths(beams, 30f64.to_radians());
    let mut image = encode::level_ping(
        1_700_000_000_000_000_000,
        &azimuths,
        &ranges,
        1500.0,
        2,
        data,
    );
    image.ping_info.tx_beamwidths = vec![0.24];
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let tf = TransformStamped {
        header: Header {
            stamp_ns: 1_700_000_000_000_000_000,
            frame_id: "map".into(),
        },
        child_frame_id: "sonar_image".into(),
        translation: [0.0; 3],
        rotation: [s, 0.0, s, 0.0],
    };
    let image = encode::cdr::sonar_image(&image);
    let tf = encode::cdr::tf_message(&[tf]);
    let entries = [
        Entry {
            topic: "/tf",
            schema: TF_MESSAGE,
            log_time: 1,
            data: &tf,
        },
        Entry {
            topic: "/sonar",
            schema: PROJECTED_SONAR_IMAGE,
            log_time: 2,
            data: &image,
        },
    ];
    for (name, c) in [
        ("none", Compression::None),
        ("lz4", Compression::Lz4),
        ("zstd", Compression::Zstd),
    ] {
        let mut whole = vec![0u8];
        whole.extend(bag(&entries, c));
        std::fs::write(dir.join(format!("bag-{name}")), whole)?;
    }
    for mode in 1u8..=3 {
        let mut split = vec![mode];
        split.extend((image.len() as u16).to_le_bytes());
        split.extend(&image);
        split.extend(&tf);
        std::fs::write(dir.join(format!("split-{mode}")), split)?;
    }
    Ok(())
}
