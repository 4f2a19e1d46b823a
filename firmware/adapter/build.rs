//! With the `http` feature: the device's page (`src/http/page.html`) made
//! ready to serve from flash. Each line loses its indentation, blank lines
//! and lines that are `//` comments go, and the rest is gzipped (RFC 1952)
//! at miniz_oxide's highest level into `OUT_DIR/page.html.gz`, which
//! `http::page::PAGE` includes. The source stays readable; the image
//! carries only the compressed bytes.

use std::error::Error;

fn main() -> Result<(), Box<dyn Error>> {
    println!("cargo::rerun-if-changed=build.rs");
    #[cfg(feature = "http")]
    page::build()?;
    Ok(())
}

#[cfg(feature = "http")]
mod page {
    use std::error::Error;
    use std::path::PathBuf;

    const SOURCE: &str = "src/http/page.html";

    /// miniz_oxide's best (and slowest) level: the page is compressed once
    /// per build, and every byte saved is flash.
    const LEVEL: u8 = 10;

    pub fn build() -> Result<(), Box<dyn Error>> {
        println!("cargo::rerun-if-changed={SOURCE}");
        let html = std::fs::read_to_string(SOURCE).map_err(|e| format!("{SOURCE}: {e}"))?;
        let served = gzip(strip(&html).as_bytes())?;
        let out = PathBuf::from(std::env::var("OUT_DIR")?).join("page.html.gz");
        std::fs::write(&out, served).map_err(|e| format!("{}: {e}", out.display()))?;
        Ok(())
    }

    /// The page without indentation, blank lines or `//` comment lines (the
    /// unit tests in `src/http/page.rs` check the served page against it).
    fn strip(html: &str) -> String {
        let mut out = String::with_capacity(html.len());
        for line in html.lines().map(str::trim).filter(|line| !line.is_empty() && !line.starts_with("//")) {
            out.push_str(line);
            out.push('\n');
        }
        out
    }

    /// One gzip member (RFC 1952 section 2.3): no name, no time (the build
    /// is reproducible), the deflate stream, its CRC-32 and length.
    fn gzip(data: &[u8]) -> Result<Vec<u8>, Box<dyn Error>> {
        const MAGIC: [u8; 2] = [0x1f, 0x8b];
        const DEFLATE: u8 = 8;
        const NO_FLAGS: u8 = 0;
        const NO_TIME: [u8; 4] = [0; 4];
        const BEST_COMPRESSION: u8 = 2;
        const UNKNOWN_OS: u8 = 255;
        let len = u32::try_from(data.len())?;
        let mut out = Vec::new();
        out.extend(MAGIC);
        out.extend([DEFLATE, NO_FLAGS]);
        out.extend(NO_TIME);
        out.extend([BEST_COMPRESSION, UNKNOWN_OS]);
        out.extend(miniz_oxide::deflate::compress_to_vec(data, LEVEL));
        out.extend(crc32(data).to_le_bytes());
        out.extend(len.to_le_bytes());
        Ok(out)
    }

    /// CRC-32 as gzip uses it (RFC 1952 section 8: ISO 3309, the reflected
    /// polynomial 0xEDB88320), a bit at a time: a few kilobytes per build.
    fn crc32(data: &[u8]) -> u32 {
        const POLYNOMIAL: u32 = 0xedb8_8320;
        let mut crc = !0u32;
        for &byte in data {
            crc ^= u32::from(byte);
            for _ in 0..8 {
                crc = if crc & 1 == 1 { (crc >> 1) ^ POLYNOMIAL } else { crc >> 1 };
            }
        }
        !crc
    }
}
