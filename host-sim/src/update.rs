//! Keys and signed update images on the host: `host-sim keygen` and `host-sim sign`
//! (docs/UPDATE.md). Key files are the raw 32 bytes: `private` the Ed25519 seed, `public` the
//! key the firmware is built with (`EPSSN_UPDATE_KEY=DIR/public`).

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use epssn::blob::Blob;
use epssn::config;
use epssn::crc32::crc32;
use epssn::golden;
use epssn::model::Model;
use epssn_update::image::{self, HEADER_LEN};

/// Options of `host-sim keygen`.
#[derive(Clone, Debug)]
pub struct KeygenOptions {
    /// The folder that receives `private` and `public` (created; neither file may exist).
    pub out: PathBuf,
}

/// Options of `host-sim sign`.
#[derive(Clone, Debug)]
pub struct SignOptions {
    /// The private key file (`keygen`'s `private`).
    pub key: PathBuf,
    /// The weight blob.
    pub blob: PathBuf,
    /// The model version (1 or more; a device takes only a version above the one it serves).
    pub version: u32,
    /// The signed update image to write.
    pub out: PathBuf,
}

/// Reads a 32-byte key file.
pub fn read_key(path: &Path) -> Result<[u8; 32]> {
    let bytes = fs::read(path).with_context(|| format!("reading key {}", path.display()))?;
    bytes
        .as_slice()
        .try_into()
        .map_err(|_| anyhow::anyhow!("{}: {} bytes, a key has 32", path.display(), bytes.len()))
}

/// Writes `bytes` to `path` through a new temporary file beside it, renamed onto `path`, so a
/// failure leaves nothing new.
fn write_new(path: &Path, bytes: &[u8], private: bool) -> Result<()> {
    let tmp = path.with_extension("tmp");
    let mut open = fs::OpenOptions::new();
    open.write(true).create_new(true);
    #[cfg(unix)]
    if private {
        use std::os::unix::fs::OpenOptionsExt;
        open.mode(0o600);
    }
    #[cfg(not(unix))]
    let _ = private;
    let mut f = open
        .open(&tmp)
        .with_context(|| format!("creating {}", tmp.display()))?;
    let written = f.write_all(bytes).and_then(|()| f.sync_all());
    let renamed = written.and_then(|()| fs::rename(&tmp, path));
    if let Err(e) = renamed {
        let _ = fs::remove_file(&tmp);
        return Err(e).with_context(|| format!("writing {}", path.display()));
    }
    Ok(())
}

/// `host-sim keygen`: a new Ed25519 key pair from the operating system's randomness.
pub fn keygen(o: &KeygenOptions, out: &mut impl Write) -> Result<()> {
    let (private, public) = (o.out.join("private"), o.out.join("public"));
    for p in [&private, &public] {
        ensure!(
            !p.exists(),
            "{} exists: keygen never overwrites a key",
            p.display()
        );
    }
    let mut seed = [0u8; 32];
    getrandom::fill(&mut seed).map_err(|e| anyhow::anyhow!("no randomness: {e}"))?;
    let key = epssn_update::verify::public_key(&seed);
    fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    write_new(&private, &seed, true)?;
    if let Err(e) = write_new(&public, &key, false) {
        let _ = fs::remove_file(&private);
        return Err(e);
    }
    writeln!(out, "private {}", private.display())?;
    writeln!(out, "public  {} ({})", public.display(), hex(&key))?;
    Ok(())
}

/// `host-sim sign`: the blob as model `version`, signed, in one update image.
pub fn sign(o: &SignOptions, out: &mut impl Write) -> Result<()> {
    ensure!(
        o.version >= 1,
        "version 0 is the compiled-in model's: use 1 or more"
    );
    let secret = read_key(&o.key)?;
    let blob = fs::read(&o.blob).with_context(|| format!("reading {}", o.blob.display()))?;
    // Format and CRC, against the spec hash the blob names: a blob of another spec is signed
    // (a device built for another spec refuses it at the commit), a corrupt one is not.
    let spec_hash = blob
        .get(12..16)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .unwrap_or(0);
    if let Err(e) = Blob::parse(&blob, spec_hash) {
        bail!("{}: not a weight blob: {e:?}", o.blob.display());
    }
    // The depth map the device's self-test must reproduce with this blob before it serves: of
    // this build's spec only (a blob of another spec is refused at the commit anyway).
    let golden = if spec_hash == config::SPEC_HASH {
        let model = Model::from_blob(&blob)
            .map_err(|e| anyhow::anyhow!("{}: refused by the model: {e:?}", o.blob.display()))?;
        let depth = golden::depth(&model)
            .map_err(|e| anyhow::anyhow!("{}: golden pair: {e:?}", o.blob.display()))?;
        golden::depth_crc(&depth)
    } else {
        0
    };
    let header = image::sign(&secret, o.version, golden, &blob).to_bytes();
    let mut img = Vec::with_capacity(HEADER_LEN + blob.len());
    img.extend_from_slice(&header);
    img.extend_from_slice(&blob);
    // Through a temporary file renamed over any old image: a failure leaves the old one.
    write_new(&o.out, &img, false)?;
    let spec = if spec_hash == config::SPEC_HASH {
        format!("{} ({spec_hash:08x})", config::SPEC_NAME)
    } else {
        format!("{spec_hash:08x}, not this build's {}", config::SPEC_NAME)
    };
    writeln!(
        out,
        "signed {}: version {}, blob {} bytes, image {} bytes, id {:08x}, spec {spec}",
        o.out.display(),
        o.version,
        blob.len(),
        img.len(),
        crc32(&header)
    )?;
    Ok(())
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keygen_then_sign_gives_an_image_the_public_key_verifies() {
        let dir = tempfile::tempdir().unwrap();
        let keys = dir.path().join("keys");
        keygen(&KeygenOptions { out: keys.clone() }, &mut Vec::new()).unwrap();
        assert!(keygen(&KeygenOptions { out: keys.clone() }, &mut Vec::new()).is_err());
        let blob = dir.path().join("b.bin");
        fs::copy("../weights/site-tank/epssn-s.q8.bin", &blob).unwrap();
        let o = SignOptions {
            key: keys.join("private"),
            blob: blob.clone(),
            version: 3,
            out: dir.path().join("s.bin"),
        };
        sign(&o, &mut Vec::new()).unwrap();
        let img = fs::read(&o.out).unwrap();
        let public = read_key(&keys.join("public")).unwrap();
        let h = image::Header::parse(&img, img.len()).unwrap();
        assert_eq!(h.version, 3);
        let m = h.message(&img[HEADER_LEN..]);
        // The golden CRC is the library's own on the golden pair with this blob.
        let model = Model::from_blob(&img[HEADER_LEN..]).unwrap();
        assert_eq!(h.golden, golden::depth_crc(&golden::depth(&model).unwrap()));
        assert!(epssn_update::verify::verify(&public, &m, &h.signature));
        // A corrupt blob is not signed and nothing is written.
        let mut bad = fs::read(&blob).unwrap();
        bad[500] ^= 1;
        fs::write(&blob, bad).unwrap();
        let o2 = SignOptions {
            out: dir.path().join("s2.bin"),
            ..o
        };
        assert!(sign(&o2, &mut Vec::new()).is_err());
        assert!(!o2.out.exists());
    }
}
