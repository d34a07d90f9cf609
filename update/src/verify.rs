//! The signature check and the blob's digest: Ed25519 (RFC 8032) and SHA-512 through salty.

/// Whether `signature` is `key`'s over `message`. Never inlined: its kilobytes of stack (curve
/// points, the hash state) are gone before the commit's self-test runs its network.
#[inline(never)]
pub fn verify(key: &[u8; 32], message: &[u8], signature: &[u8; 64]) -> bool {
    let Ok(key) = salty::PublicKey::try_from(key) else {
        return false;
    };
    key.verify(message, &salty::Signature::from(signature))
        .is_ok()
}

/// SHA-512 of `bytes`. Never inlined, as [`verify`].
#[inline(never)]
pub fn sha512(bytes: &[u8]) -> [u8; 64] {
    salty::Sha512::new().updated(bytes).finalize()
}

/// The signature of `message` by the private key (seed) `secret`.
pub fn sign(secret: &[u8; 32], message: &[u8]) -> [u8; 64] {
    salty::Keypair::from(secret).sign(message).to_bytes()
}

/// The public half of the private key (seed) `secret`.
pub fn public_key(secret: &[u8; 32]) -> [u8; 32] {
    salty::PublicKey::from(&salty::SecretKey::from(secret)).to_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex<const N: usize>(s: &str) -> [u8; N] {
        let mut out = [0u8; N];
        for (i, o) in out.iter_mut().enumerate() {
            *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap();
        }
        out
    }

    // RFC 8032 section 7.1, TEST 3: another implementation's key and signature verify here.
    const SECRET: &str = "c5aa8df43f9f837bedb7442f31dcb7b166d38535076f094b85ce3a2e0b4458f7";
    const PUBLIC: &str = "fc51cd8e6218a1a38da47ed00230f0580816ed13ba3303ac5deb911548908025";
    const SIG: &str = "6291d657deec24024827e69c3abe01a30ce548a284743a445e3680d7db5ac3ac\
                       18ff9b538d16f290ae67f760984dc6594a7c15e9716ed28dc027beceea1ec40a";

    #[test]
    fn rfc8032_vector_signs_and_verifies() {
        let (secret, public, sig) = (hex::<32>(SECRET), hex::<32>(PUBLIC), hex::<64>(SIG));
        assert_eq!(public_key(&secret), public);
        let key = salty::PublicKey::try_from(&public).unwrap();
        assert!(key
            .verify(&[0xaf, 0x82], &salty::Signature::from(&sig))
            .is_ok());
        let mut bad = sig;
        bad[0] ^= 1;
        assert!(key
            .verify(&[0xaf, 0x82], &salty::Signature::from(&bad))
            .is_err());
    }

    #[test]
    fn the_test_key_pair_agrees_with_openssl() {
        // update/test-key/public was derived from `private` by OpenSSL (Python's
        // cryptography), not by this crate.
        let secret: [u8; 32] = *include_bytes!("../test-key/private");
        assert_eq!(public_key(&secret), *include_bytes!("../test-key/public"));
    }

    #[test]
    fn verify_takes_only_the_signers_key() {
        let m = [7u8; 96]; // an update image's message length
        let s = sign(&[1; 32], &m);
        assert!(verify(&public_key(&[1; 32]), &m, &s));
        assert!(!verify(&public_key(&[2; 32]), &m, &s));
        let mut m2 = m;
        m2[95] ^= 0x80;
        assert!(!verify(&public_key(&[1; 32]), &m2, &s));
    }
}
