"""What the programs share (the command line, a bag through the engine, the receivers' formats, a bounded HTTP
poll): imported by reporting, ros and tools, it imports only the engine and msgs_adapters."""
