//! The namespace fixture itself: the TAP exists inside, not outside, and the
//! namespace is gone after drop.

use std::process::Command;
use system_tests::netns::{Namespace, TAP};

#[test]
fn namespace_holds_the_tap_and_is_removed_on_drop() {
    let ns = Namespace::new().unwrap();
    let name = ns.name().to_owned();
    let inside = ns.command("ip").args(["-brief", "addr", "show", TAP]).output().unwrap();
    assert!(String::from_utf8_lossy(&inside.stdout).contains("198.18.0.1/24"));
    let outside = Command::new("ip").args(["link", "show", TAP]).output().unwrap();
    assert!(!outside.status.success(), "the TAP must not exist in the host's namespace");
    drop(ns);
    let list = Command::new("ip").args(["netns", "list"]).output().unwrap();
    assert!(!String::from_utf8_lossy(&list.stdout).contains(&name));
}
