from terra.cli import main

main()
