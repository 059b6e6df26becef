"""Publishing: the status hub, the control socket, MQTT, Home Assistant, notifications, history."""
