"""The source node: the clip whose style is imitated enters the dataflow (`cinetransfer source`)."""
