//! `sign-firmware`: makes the adapter's firmware update files
//! (docs/update.md; the format is `update-image`'s).
//!
//! ```text
//! sign-firmware keygen -o NAME                  # NAME.key (secret) and NAME.pub (public)
//! sign-firmware [sign] --key KEY --board BOARD --version X.Y.Z APP.bin -o APP.update
//! sign-firmware verify --public-key PUB [--board BOARD] APP.update
//! sign-firmware show APP.update
//! ```
//!
//! Keys are text files: lines starting with `#` are comments, the rest is
//! 64 hexadecimal digits (the ed25519 secret key's 32-byte seed, or the
//! public key). The firmware builds the public key in (`UPDATE_PUBLIC_KEY`,
//! the path of a `.pub` file; `keys/update-dev.pub` unless set).

use std::fs;
use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use ed25519_dalek::{Signer as _, SigningKey};
use update_image::{Board, HEADER_LEN, Header, PUBLIC_KEY_LEN, SIGNATURE_LEN, Version};

const USAGE: &str = "\
usage:
  sign-firmware keygen -o NAME
      a new key pair: NAME.key (secret: keep it off the device and out of
      the repository) and NAME.pub (the public key the firmware builds in)
  sign-firmware [sign] --key KEY --board BOARD --version X.Y.Z APP.bin -o OUT
      signs the flat application binary APP.bin (not an ELF file:
      llvm-objcopy -O binary app.elf app.bin) for BOARD (the board crate's
      name: mps2-an386, nucleo-f429zi) as firmware version X.Y.Z
  sign-firmware verify --public-key PUB [--board BOARD] FILE
      checks FILE's header, length and signature (and board) as the device does
  sign-firmware show FILE
      prints FILE's header";

/// How a run went wrong: a usage error (exit 2) or a failure (exit 1).
#[derive(Debug, PartialEq, Eq)]
enum Error {
    Usage(String),
    Failed(String),
}

fn failed(message: impl Into<String>) -> Error {
    Error::Failed(message.into())
}

fn usage(message: impl Into<String>) -> Error {
    Error::Usage(message.into())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(report) => {
            println!("{report}");
            ExitCode::SUCCESS
        }
        Err(Error::Usage(message)) => {
            eprintln!("sign-firmware: {message}\n\n{USAGE}");
            ExitCode::from(2)
        }
        Err(Error::Failed(message)) => {
            eprintln!("sign-firmware: {message}");
            ExitCode::FAILURE
        }
    }
}

/// Runs one command; what it made or found, as text.
fn run(args: &[String]) -> Result<String, Error> {
    match args.first().map(String::as_str) {
        None | Some("-h" | "--help" | "help") => Ok(USAGE.to_string()),
        Some("keygen") => keygen(&Options::parse(args.get(1..).unwrap_or_default(), &["-o"])?),
        Some("verify") => verify(&Options::parse(args.get(1..).unwrap_or_default(), &["--public-key", "--board"])?),
        Some("show") => show(&Options::parse(args.get(1..).unwrap_or_default(), &[])?),
        Some("sign") => sign(&Options::parse(args.get(1..).unwrap_or_default(), SIGN_OPTIONS)?),
        Some(_) => sign(&Options::parse(args, SIGN_OPTIONS)?),
    }
}

const SIGN_OPTIONS: &[&str] = &["--key", "--board", "--version", "-o"];

/// A command's options (`--name value`, each once) and its one file.
#[derive(Debug, Default)]
struct Options {
    values: Vec<(String, String)>,
    file: Option<PathBuf>,
}

impl Options {
    fn parse(args: &[String], known: &[&str]) -> Result<Self, Error> {
        let mut options = Self::default();
        let mut args = args.iter();
        while let Some(arg) = args.next() {
            if arg.starts_with('-') && arg != "-" {
                if !known.contains(&arg.as_str()) {
                    return Err(usage(format!("unknown option {arg}")));
                }
                let value = args.next().ok_or_else(|| usage(format!("{arg} needs a value")))?;
                if options.get(arg).is_some() {
                    return Err(usage(format!("{arg} given twice")));
                }
                options.values.push((arg.clone(), value.clone()));
            } else if options.file.replace(PathBuf::from(arg)).is_some() {
                return Err(usage("more than one input file"));
            }
        }
        Ok(options)
    }

    fn get(&self, name: &str) -> Option<&str> {
        self.values.iter().find(|(key, _)| key == name).map(|(_, value)| value.as_str())
    }

    fn required(&self, name: &str) -> Result<&str, Error> {
        self.get(name).ok_or_else(|| usage(format!("{name} is required")))
    }

    fn file(&self) -> Result<&Path, Error> {
        self.file.as_deref().ok_or_else(|| usage("no input file"))
    }
}

fn keygen(options: &Options) -> Result<String, Error> {
    if options.file.is_some() {
        return Err(usage("keygen takes no input file"));
    }
    let name = options.required("-o")?;
    let (secret_path, public_path) = (format!("{name}.key"), format!("{name}.pub"));
    for path in [&secret_path, &public_path] {
        if Path::new(path).exists() {
            return Err(failed(format!("{path} exists: not overwriting a key")));
        }
    }
    let mut seed = [0u8; 32];
    fs::File::open("/dev/urandom")
        .and_then(|mut random| random.read_exact(&mut seed))
        .map_err(|e| failed(format!("/dev/urandom: {e}")))?;
    let key = SigningKey::from_bytes(&seed);
    let public = key.verifying_key().to_bytes();
    write_new(
        &secret_path,
        &format!("# ed25519 secret key (seed) for signing adapter firmware updates. Keep it secret.\n{}\n", hex(&seed)),
        0o600,
    )?;
    write_new(
        &public_path,
        &format!("# ed25519 public key for adapter firmware updates (UPDATE_PUBLIC_KEY).\n{}\n", hex(&public)),
        0o644,
    )?;
    Ok(format!("wrote {secret_path} (secret) and {public_path} (public key {})", hex(&public)))
}

/// Writes a file that must not exist yet, with `mode`.
fn write_new(path: &str, text: &str, mode: u32) -> Result<(), Error> {
    use std::io::Write as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .and_then(|mut file| file.write_all(text.as_bytes()))
        .map_err(|e| failed(format!("{path}: {e}")))
}

fn sign(options: &Options) -> Result<String, Error> {
    // Every usage error before any file is read.
    let key_path = options.required("--key")?;
    let board_name = options.required("--board")?;
    let board = Board::new(board_name)
        .ok_or_else(|| usage(format!("--board {board_name}: 1-32 of a-z 0-9 - (the board crate's name)")))?;
    let version_text = options.required("--version")?;
    let version = Version::parse(version_text)
        .ok_or_else(|| usage(format!("--version {version_text}: X.Y.Z, each part 0-65535")))?;
    let out = options.required("-o")?;
    let input = options.file()?;
    let key = SigningKey::from_bytes(&read_key(Path::new(key_path))?);
    let payload = fs::read(input).map_err(|e| failed(format!("{}: {e}", input.display())))?;
    if payload.starts_with(b"\x7fELF") {
        return Err(failed(format!(
            "{} is an ELF file: sign the flat binary (llvm-objcopy -O binary {0} app.bin)",
            input.display()
        )));
    }
    let image = signed_image(&key, board, version, &payload)?;
    fs::write(out, &image).map_err(|e| failed(format!("{out}: {e}")))?;
    Ok(format!("wrote {out}: {board} {version}, {} bytes of payload, signed", payload.len()))
}

/// The update file of `payload`: the header signed with `key`, then the payload.
fn signed_image(key: &SigningKey, board: Board, version: Version, payload: &[u8]) -> Result<Vec<u8>, Error> {
    let payload_len = u32::try_from(payload.len()).map_err(|_| failed("the payload is larger than 4 GiB"))?;
    if payload_len == 0 {
        return Err(failed("the payload is empty"));
    }
    let mut header = Header { board, version, payload_len, signature: [0; SIGNATURE_LEN] };
    let mut digest = header.digest();
    digest.update(payload);
    header.signature = key.sign(&digest.finalize()).to_bytes();
    let mut image = Vec::with_capacity(HEADER_LEN + payload.len());
    image.extend_from_slice(&header.emit());
    image.extend_from_slice(payload);
    Ok(image)
}

fn verify(options: &Options) -> Result<String, Error> {
    let public = read_key(Path::new(options.required("--public-key")?))?;
    let path = options.file()?;
    let image = fs::read(path).map_err(|e| failed(format!("{}: {e}", path.display())))?;
    let header = check(&image, &public, options.get("--board"))?;
    Ok(format!(
        "{}: good: {} {}, {} bytes, signed by {}",
        path.display(),
        header.board,
        header.version,
        header.payload_len,
        hex(&public)
    ))
}

/// Checks an update file as the device does: header, board, length, signature.
fn check(image: &[u8], public: &[u8; PUBLIC_KEY_LEN], board: Option<&str>) -> Result<Header, Error> {
    let header = Header::parse(image).map_err(|e| failed(format!("bad header: {e}")))?;
    if let Some(board) = board
        && header.board.as_str() != board
    {
        return Err(failed(format!("the image is for {}, not {board}", header.board)));
    }
    let payload = image.get(HEADER_LEN..).unwrap_or_default();
    if payload.len() != header.payload_len as usize {
        return Err(failed(format!(
            "the header says {} bytes of payload, the file has {}",
            header.payload_len,
            payload.len()
        )));
    }
    let mut digest = header.digest();
    digest.update(payload);
    header.verify(public, &digest.finalize()).map_err(|e| failed(format!("bad signature: {e}")))?;
    Ok(header)
}

fn show(options: &Options) -> Result<String, Error> {
    let path = options.file()?;
    let image = fs::read(path).map_err(|e| failed(format!("{}: {e}", path.display())))?;
    let header = Header::parse(&image).map_err(|e| failed(format!("bad header: {e}")))?;
    let actual = image.len().saturating_sub(HEADER_LEN);
    Ok(format!(
        "board {}\nversion {}\npayload {} bytes (the file has {actual})\nsignature {}",
        header.board,
        header.version,
        header.payload_len,
        hex(&header.signature)
    ))
}

/// A 32-byte key from a key file: `#` comment lines, then 64 hex digits.
fn read_key(path: &Path) -> Result<[u8; 32], Error> {
    let text = fs::read_to_string(path).map_err(|e| failed(format!("{}: {e}", path.display())))?;
    parse_key(&text).ok_or_else(|| failed(format!("{}: not a key file (64 hex digits)", path.display())))
}

fn parse_key(text: &str) -> Option<[u8; 32]> {
    let digits: String =
        text.lines().map(str::trim).filter(|line| !line.is_empty() && !line.starts_with('#')).collect();
    if digits.len() != 64 || !digits.is_ascii() {
        return None;
    }
    let mut key = [0u8; 32];
    for (byte, pair) in key.iter_mut().zip(digits.as_bytes().chunks(2)) {
        *byte = u8::from_str_radix(std::str::from_utf8(pair).ok()?, 16).ok()?;
    }
    Some(key)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::indexing_slicing)]

    use super::*;

    fn args(line: &str) -> Vec<String> {
        line.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn keys_read_as_hex_after_comments() {
        let text = "# a comment\n\n000102030405060708090a0b0c0d0e0f\n101112131415161718191A1B1C1D1E1F\n";
        let key = parse_key(text).unwrap();
        assert_eq!(key[0], 0);
        assert_eq!(key[31], 0x1f);
        assert_eq!(hex(&key), "000102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f");
        for bad in ["", "00", &"0".repeat(66), &"g".repeat(64), &"é".repeat(32)] {
            assert_eq!(parse_key(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn options_take_each_name_once_and_one_file() {
        let options = Options::parse(&args("--key k --board b app.bin -o out"), SIGN_OPTIONS).unwrap();
        assert_eq!(options.get("--key"), Some("k"));
        assert_eq!(options.file().unwrap(), Path::new("app.bin"));
        for bad in ["--key", "--key a --key b", "a b", "--nope x"] {
            assert!(matches!(Options::parse(&args(bad), SIGN_OPTIONS), Err(Error::Usage(_))), "{bad}");
        }
    }

    #[test]
    fn a_signed_image_checks_and_a_changed_one_does_not() {
        let key = SigningKey::from_bytes(&[3; 32]);
        let public = key.verifying_key().to_bytes();
        let board = Board::new("mps2-an386").unwrap();
        let version = Version { major: 1, minor: 0, patch: 2 };
        let image = signed_image(&key, board, version, &[0xaa; 1000]).unwrap();
        assert_eq!(image.len(), HEADER_LEN + 1000);
        let header = check(&image, &public, Some("mps2-an386")).unwrap();
        assert_eq!((header.version, header.payload_len), (version, 1000));

        assert!(check(&image, &public, Some("nucleo-f429zi")).is_err());
        assert!(check(&image[..image.len() - 1], &public, None).is_err());
        let mut changed = image.clone();
        changed[HEADER_LEN + 500] ^= 0x80;
        assert!(check(&changed, &public, None).is_err());
        assert!(check(&image, &SigningKey::from_bytes(&[4; 32]).verifying_key().to_bytes(), None).is_err());
        assert!(signed_image(&key, board, version, &[]).is_err());
    }
}
