// A memory map's regions, read by the boards' build scripts (`include!`d
// by the build scripts of firmware/nucleo-f429zi, nucleo-f429zi-boot and mps2-an386-boot:
// a build script cannot depend on a crate of the workspace it builds).

/// ORIGIN and LENGTH of the MEMORY region `name`, from its line
/// `NAME [(attributes)] : ORIGIN = 0x..., LENGTH = 32K` (hexadecimal or decimal, with an
/// optional K or M).
fn region(map: &str, name: &str) -> Option<(u32, u32)> {
    map.lines().find_map(|line| {
        let (region, fields) = line.split_once(':')?;
        if region.split_whitespace().next() != Some(name) {
            return None;
        }
        let (mut origin, mut length) = (None, None);
        for field in fields.split(',') {
            let (key, value) = field.split_once('=')?;
            match key.trim() {
                "ORIGIN" | "org" | "o" => origin = number(value),
                "LENGTH" | "len" | "l" => length = number(value),
                _ => return None,
            }
        }
        Some((origin?, length?))
    })
}

fn number(text: &str) -> Option<u32> {
    let text = text.trim();
    let (digits, scale) = match text.strip_suffix('K') {
        Some(digits) => (digits, 1 << 10),
        None => match text.strip_suffix('M') {
            Some(digits) => (digits, 1 << 20),
            None => (text, 1),
        },
    };
    let value = match digits.strip_prefix("0x").or_else(|| digits.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => digits.parse(),
    };
    value.ok()?.checked_mul(scale)
}
