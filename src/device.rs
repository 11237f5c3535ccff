//! Placeholder until the device state machine lands.
