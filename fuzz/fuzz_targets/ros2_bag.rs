//! The ROS 2 bag reader (MCAP, CDR of ProjectedSonarImage and TFMessage) on arbitrary bytes.
//! The first byte picks the input's shape: 0, the rest is a whole MCAP file; 1, 2 or 3, the
//! rest is a ProjectedSonarImage's CDR (its length in the next two bytes, little endian) and a
//! TFMessage's CDR, written into a bag whose chunk is stored, LZ4- or zstd-compressed, so the
//! mutations reach the message decoders through every decompressor. Every ping read is
//! resampled onto the model's grid. It must refuse or read without panicking.
#![no_main]

use epssn_ros2::bag::BagRecording;
use epssn_ros2::encode::{bag, Compression, Entry};
use epssn_ros2::msgs::{PROJECTED_SONAR_IMAGE, TF_MESSAGE};
use libfuzzer_sys::fuzz_target;

fn read(bytes: &[u8]) {
    let Ok(rec) = BagRecording::from_bytes(bytes, None) else {
        return;
    };
    for i in 0..rec.frame_count() {
        if let Ok(frame) = rec.frame(i) {
            let _ = epssn_ros2::fit::misfit(&frame);
            let _ = frame.to_polar();
        }
        let _ = (rec.roll_deg(i), rec.attitude(i));
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let compression = match mode % 4 {
        0 => return read(rest),
        1 => Compression::None,
        2 => Compression::Lz4,
        _ => Compression::Zstd,
    };
    if rest.len() < 2 {
        return;
    }
    let n = (usize::from(rest[0]) | usize::from(rest[1]) << 8).min(rest.len() - 2);
    let (image, tf) = rest[2..].split_at(n);
    let entries = [
        Entry {
            topic: "/tf",
            schema: TF_MESSAGE,
            log_time: 1,
            data: tf,
        },
        Entry {
            topic: "/sonar",
            schema: PROJECTED_SONAR_IMAGE,
            log_time: 2,
            data: image,
        },
    ];
    read(&bag(&entries, compression));
});
