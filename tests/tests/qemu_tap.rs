//! The same firmware image on a TAP inside a network namespace (as hal-sim's
//! tests run): no DHCP server there, so the firmware falls back to its static
//! address 198.18.0.2/24, and a Modbus client in the namespace reaches it.
//! Needs root (CAP_NET_ADMIN), like every namespace test.

use system_tests::qemu::{LED0, NO_ROBOT, Qemu, ROBOT_REGISTERS};
use tokio_modbus::client::{Reader as _, Writer as _};

#[test]
fn the_image_answers_on_a_tap_in_a_network_namespace() {
    let qemu = Qemu::tap();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        let robot = ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap();
        assert_eq!(robot, NO_ROBOT);
        ctx.write_single_coil(16, true).await.unwrap().unwrap();
        assert_eq!(ctx.read_coils(16, 1).await.unwrap().unwrap(), [true]);
    });
    assert_eq!(qemu.read_word(LED0), 0b01, "coil 16 lit LED0");
    let log = qemu.finish();
    assert!(log.contains("no DHCP lease after 5 s: using the static address"), "{log}");
    assert!(log.contains("Modbus TCP server at 198.18.0.2:502"), "{log}");
}
