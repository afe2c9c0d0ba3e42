from tetweave_codec.cli.main import main

main()
