"""A mission's team security: certificates, identities and Zenoh access-control rules (docs/security.md)."""
