//! The device's page (`GET /`, docs/http-api.md): one self-contained
//! HTML document (inline CSS and JS, nothing fetched from elsewhere), kept
//! readable in `page.html` and served from flash as build.rs made it:
//! indentation, blank lines and `//` comment lines stripped, then gzipped.
//!
//! The page polls `GET /api/status` every 500 ms, one request at a time
//! (the server has two connections and closes each after its request, so
//! it holds none open, and leaves the other to another client), builds
//! its settings form from `GET /api/settings` and changes the device only
//! through the API. It is sent gzipped, and only to a client that takes
//! gzip ([`accepts_gzip`]): the device keeps no uncompressed copy.

/// The page as served: `page.html` stripped and gzipped by build.rs (RFC
/// 1952), in flash.
pub static PAGE: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/page.html.gz"));

/// The most the page may be as served (docs/http-api.md).
pub const MAX_PAGE_LEN: usize = 24 * 1024;

const _: () = assert!(PAGE.len() <= MAX_PAGE_LEN, "the page is over 24 KiB as served");

pub const CONTENT_TYPE: &str = "text/html; charset=utf-8";

/// The `Content-Security-Policy` every response carries (build.rs writes
/// it): nothing loads or runs but the page's own script and style, named
/// by their SHA-256, and connections to the device itself.
pub const CONTENT_SECURITY_POLICY: &str = include_str!(concat!(env!("OUT_DIR"), "/page_csp.txt"));

/// The `Content-Encoding` of [`PAGE`].
pub const ENCODING: &str = "gzip";

/// The 406 to a client that does not take gzip.
pub const NOT_ACCEPTABLE: &str = "the page is sent gzipped only: use a browser, or curl --compressed";

/// Whether a request with this `Accept-Encoding` takes the gzipped page:
/// whether it names `gzip`, in any case (so `x-gzip` too). Weights are
/// not read: no client lists gzip only to refuse it (`gzip;q=0`), and
/// reading them (a state machine over the list) cost five times this in
/// flash, about 500 bytes against 100. No header: no. RFC 9110
/// would allow any coding then, but the clients that send none (curl
/// without `--compressed`) cannot show gzip, and are better told why (406).
pub fn accepts_gzip(header: Option<&[u8]>) -> bool {
    header.is_some_and(|header| header.windows(4).any(|name| name.eq_ignore_ascii_case(b"gzip")))
}

#[cfg(test)]
pub(super) mod tests {
    use std::io::Read;

    use super::*;

    /// The page as build.rs serves it, said again here: each line trimmed,
    /// blank lines and `//` comment lines dropped.
    fn stripped_source() -> String {
        let source = include_str!("page.html");
        let lines = source.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with("//"));
        lines.map(|line| format!("{line}\n")).collect()
    }

    /// The page decompressed by an independent gzip decoder, which checks
    /// the header, the CRC-32 and the length.
    pub(in crate::http) fn decompressed(served: &[u8]) -> String {
        let mut html = String::new();
        flate2::read::GzDecoder::new(served).read_to_string(&mut html).expect("a whole gzip member of UTF-8");
        html
    }

    #[test]
    fn the_page_is_the_source_gzipped() {
        assert_eq!(PAGE.get(..3), Some(&[0x1f, 0x8b, 8][..]), "gzip, deflate");
        let html = decompressed(PAGE);
        assert_eq!(html, stripped_source());
        assert!(html.starts_with("<!DOCTYPE html>\n"), "{html}");
        assert!(html.ends_with("</html>\n"));
    }

    #[test]
    fn the_page_stays_under_its_limit_and_fetches_nothing_from_elsewhere() {
        assert!(PAGE.len() <= MAX_PAGE_LEN, "{} bytes served", PAGE.len());
        let html = decompressed(PAGE);
        for external in ["http:", "https:", "src=", "@import", "url("] {
            assert!(!html.contains(external), "{external} in the page: it loads nothing from a file or elsewhere");
        }
    }

    #[test]
    fn a_client_that_names_gzip_takes_the_page() {
        let taken = |header: &str| accepts_gzip(Some(header.as_bytes()));
        for header in ["gzip", "gzip, deflate, br, zstd", "deflate, GZip;q=0.5", "x-gzip", " gzip ; q=1 "] {
            assert!(taken(header), "{header:?} takes gzip");
        }
        for header in ["", "identity", "deflate, br", "*", "gzi", "g zip"] {
            assert!(!taken(header), "{header:?} does not take gzip");
        }
        assert!(!accepts_gzip(None), "no header: 406, not bytes a terminal cannot show");
    }

    #[test]
    fn any_header_is_read_without_a_panic() {
        let bytes = b"gzip;q=0.5, *;q=, ;;,,q=\xff\x00,*;q";
        for end in 0..=bytes.len() {
            for start in 0..=end {
                accepts_gzip(bytes.get(start..end));
            }
        }
    }
}
