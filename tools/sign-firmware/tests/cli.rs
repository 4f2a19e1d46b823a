//! The tool as a user runs it: keygen, sign, verify, show, and the
//! refusals, through its command line and exit codes.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn tool(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sign-firmware")).args(args).current_dir(dir).output().unwrap()
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sign-firmware-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[test]
fn keygen_sign_verify_show() {
    let dir = scratch("round");
    let made = tool(&["keygen", "-o", "mine"], &dir);
    assert!(made.status.success(), "{made:?}");
    std::fs::write(dir.join("app.bin"), vec![0x5a; 3000]).unwrap();

    let signed = tool(
        &["--key", "mine.key", "--board", "mps2-an386", "--version", "1.2.3", "app.bin", "-o", "app.update"],
        &dir,
    );
    assert!(signed.status.success(), "{signed:?}");
    assert_eq!(std::fs::metadata(dir.join("app.update")).unwrap().len(), 128 + 3000);

    let good = tool(&["verify", "--public-key", "mine.pub", "--board", "mps2-an386", "app.update"], &dir);
    assert!(good.status.success(), "{good:?}");
    let shown = tool(&["show", "app.update"], &dir);
    let text = String::from_utf8(shown.stdout).unwrap();
    assert!(text.contains("board mps2-an386") && text.contains("version 1.2.3"), "{text}");

    // The wrong board, a changed byte, a cut file: exit 1.
    let wrong = tool(&["verify", "--public-key", "mine.pub", "--board", "nucleo-f429zi", "app.update"], &dir);
    assert_eq!(wrong.status.code(), Some(1), "{wrong:?}");
    let mut image = std::fs::read(dir.join("app.update")).unwrap();
    image[1000] ^= 1;
    std::fs::write(dir.join("changed.update"), &image).unwrap();
    let changed = tool(&["verify", "--public-key", "mine.pub", "changed.update"], &dir);
    assert_eq!(changed.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&changed.stderr).contains("signature"), "{changed:?}");
    image[1000] ^= 1;
    std::fs::write(dir.join("cut.update"), &image[..2000]).unwrap();
    assert_eq!(tool(&["verify", "--public-key", "mine.pub", "cut.update"], &dir).status.code(), Some(1));

    // keygen never overwrites a key.
    assert_eq!(tool(&["keygen", "-o", "mine"], &dir).status.code(), Some(1));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_committed_development_keys_are_a_pair() {
    let dir = scratch("dev");
    std::fs::write(dir.join("app.bin"), b"application").unwrap();
    let keys = repository().join("keys");
    let key = keys.join("update-dev.key");
    let public = keys.join("update-dev.pub");
    let signed = tool(
        &[
            "sign",
            "--key",
            key.to_str().unwrap(),
            "--board",
            "mps2-an386",
            "--version",
            "0.1.0",
            "app.bin",
            "-o",
            "a.update",
        ],
        &dir,
    );
    assert!(signed.status.success(), "{signed:?}");
    let good = tool(&["verify", "--public-key", public.to_str().unwrap(), "a.update"], &dir);
    assert!(good.status.success(), "{good:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn usage_errors_and_elf_files_are_refused() {
    let dir = scratch("refuse");
    assert_eq!(tool(&["--key", "k"], &dir).status.code(), Some(2));
    assert_eq!(tool(&["sign", "--bogus", "x"], &dir).status.code(), Some(2));
    tool(&["keygen", "-o", "k"], &dir);
    std::fs::write(dir.join("app.elf"), b"\x7fELF\x01\x01\x01").unwrap();
    let elf = tool(&["--key", "k.key", "--board", "mps2-an386", "--version", "1.0.0", "app.elf", "-o", "x"], &dir);
    assert_eq!(elf.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&elf.stderr).contains("ELF"), "{elf:?}");
    let bad_board = tool(&["--key", "k.key", "--board", "MPS2", "--version", "1.0.0", "app.elf", "-o", "x"], &dir);
    assert_eq!(bad_board.status.code(), Some(2));
    let bad_version =
        tool(&["--key", "k.key", "--board", "mps2-an386", "--version", "1.0", "app.elf", "-o", "x"], &dir);
    assert_eq!(bad_version.status.code(), Some(2));
    std::fs::remove_dir_all(&dir).unwrap();
}
